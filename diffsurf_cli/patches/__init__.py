"""A target with sharp edges, flat faces and tagged regions, as smooth patches: the
segmentation (`segment`) and the surface answering each contactor by the closest patch, or
by the facets at a sharp edge (`surface.PatchedSurface`). Above both `mls` (one diffuse
surface per patch) and `facet` (the facets where the patches cannot answer)."""
