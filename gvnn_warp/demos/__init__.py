"""Demos of gvnn_warp, exposed as ``gvnn-warp`` sub-commands."""
