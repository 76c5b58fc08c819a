"""The machinery under every kernel of gvnn_warp (no numerics here):

- :mod:`.kinds`: array kinds (``"scalar"``, ``"vec3"``, ``"mat34"``...), :class:`~.kinds.FloatKernel`
  (float32/float64 overloads and each kernel's declaration of how its launches may be split);
- :mod:`.launch`: :func:`~.launch.launch` (a kernel's range cut over threads, deterministic),
  :class:`~.launch.RecordedLaunch`, :func:`~.launch.wp_launch` (``wp.launch`` with safe first loads);
- :mod:`.threads`: the thread count and the Python and OpenMP pools;
- :mod:`.cache`: the one cache of generated kernels and functions (``specialise``, ``float_overloads``);
- :mod:`.lanes`: ``@wp.func`` helpers for kernels that handle 8 pixels at a time as length-8 vectors;
- :mod:`.compat`: the Warp internals gvnn_warp uses, one adapter each;
- :mod:`.moved`: the module paths of earlier releases, kept importable.
"""
