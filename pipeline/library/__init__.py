"""A studio's own takes as the in-betweener: a motion library searched per gap and fitted to the keys.

``store``: the library folder (manifest + memory-mapped arrays); ``features``: what a frame is
matched on; ``build``: reading takes into a library (``tween library build``); ``match``: the
search and the fit of retrieved windows onto two keys; ``infer``: the library as an
:class:`pipeline.infer.api.Inbetweener` (``tween fill --library``). docs/library.md.
"""
