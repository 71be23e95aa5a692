"""Planned layouts by hierarchical domain splitting (Yang et al. 2013)."""
