"""The diffuse approximation of the paper [§3-§4.1]: basis, weight, frame, support, fit and
projection onto the local approximations, with `DiffuseSurface` as its face."""
