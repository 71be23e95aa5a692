"""Road synthesis, one module per method family: fragments (thesis ch. 4.1), random walks
through attributed intersections and the street shapes they bend by (Aliaga et al. 2008),
procedural growth (Scharl 2010), StreetGAN and raster -> graph (thesis ch. 4.2)."""
