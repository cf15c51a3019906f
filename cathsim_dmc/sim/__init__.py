"""The simulation: solver settings and force readers, the wall field, the model cache and
checks, the arena and cameras, the renderers."""
