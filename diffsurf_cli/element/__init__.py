"""The contact element on the diffuse surface and the node-to-facet element [§2, §4.2-4.3]."""
