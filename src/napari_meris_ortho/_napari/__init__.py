"""napari front end (npe2 manifest ``napari.yaml``): reader, sample data, widgets and the layer
builders they share. Thin: every computation is a call into ortho, synthesis or analysis."""
