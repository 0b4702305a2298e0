"""File formats: ENVISAT N1 products, DEM sources, GeoTIFF outputs."""
