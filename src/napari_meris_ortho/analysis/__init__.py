"""Analysis tools: disparity (ZNCC, handbook section 4.6) and DEM quality control (chapter 5)."""
