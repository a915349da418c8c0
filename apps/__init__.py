"""The applications built on the per-frame engine: ``relight filter`` (a video or image sequence
relit frame by frame, :mod:`relight.apps.filter`) and ``relight live`` (a camera relit into a
virtual camera, a preview page or a recording, :mod:`relight.apps.live`)."""
