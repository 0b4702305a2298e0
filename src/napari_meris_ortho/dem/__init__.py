"""Elevation sources (handbook section 3.1, chapter 5, Appendix C): ``geoid`` (EGM96 undulation,
vertical datums), ``base`` (``DemSource``, ``LatticeWindow``), one module per format
(``getasse``, ``srtm``, ``raster``, ``copernicus``), ``stack`` (``open_dem``: the one way to open a
DEM entry; ``DemStack``: DEMs tried in order)."""
