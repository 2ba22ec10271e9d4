# cython: language_level=3
"""placeholder"""
def ready():
    return True
