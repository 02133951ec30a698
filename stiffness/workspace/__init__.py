"""Scan layer: workspace maps, chunked and on Dask, and their figures."""
