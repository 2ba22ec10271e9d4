"""The faceted target itself: closest point on its facets, the node-to-facet baseline [§2]."""
