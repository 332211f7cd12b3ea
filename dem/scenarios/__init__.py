"""Scenarios built on the DEM engine: the vibration feeder (``feeder``), its tray (``tray``), its
items (``items``) and the pictures of a run (``render``)."""
