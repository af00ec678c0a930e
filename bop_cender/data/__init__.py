"""Datasets on disk -> typed scenes. All frame and unit conversions happen here, once."""
