"""Output files: ``cog`` (the Cloud-Optimized GeoTIFF container, streamed and compressed on
threads) and ``geotiff`` (what a mapped product's file holds: uint16 counts + scale, band
metadata; plain GeoTIFF read/write)."""
