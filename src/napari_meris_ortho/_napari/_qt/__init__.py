"""The plugin's dealings with napari's Qt window (``insertion``, ``closing``)."""
