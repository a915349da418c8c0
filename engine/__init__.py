"""The per-frame engine: a face in a video frame relit with one bundle - track, head pose, live
light, relight, warp, composite (:class:`relight.engine.frame_path.FramePath`, the one stateful
object; the stages are modules of pure functions and small classes beside it).

Layers: the engine stands on ``relight.kernels`` (the OpenCL relighting and compositing) and the
core; ``relight.service`` (the HTTP, websocket and WebRTC service) and ``relight.apps``
(``relight filter``, ``relight live``) stand on it.
"""
