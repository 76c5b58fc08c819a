"""Pure-Warp building blocks of gvnn_warp (installed as ``gvnn_warp.kernels``; never imports torch)."""
