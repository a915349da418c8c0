"""Threads are stopped by whoever starts them (issue 50): a FramePath's slow-stage workers, the
service's shared ones."""

import threading

from relight.engine.threads import Worker


def _alive(prefix: str) -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith(prefix) and t.is_alive()]


def test_a_worker_stops_its_thread_on_close_and_starts_anew_on_use():
    w = Worker("relight-test-worker")
    assert w.submit(lambda: 7).result(timeout=10) == 7
    assert _alive("relight-test-worker")
    w.close()
    assert not _alive("relight-test-worker")
    assert w.submit(lambda: 8).result(timeout=10) == 8  # used again: a new thread
    w.close()
    assert not _alive("relight-test-worker")


def _first_frames(small_capture, n: int) -> list:
    """The small capture's first ``n`` frames (RGB uint8): enough to run a path's slow stages."""
    from relight.video_read import read_frames

    res, _ = small_capture
    frames = []
    for f in read_frames(res.video):
        frames.append(f)
        if len(frames) == n:
            break
    return frames


def test_a_frame_path_stops_the_workers_it_made_and_not_the_ones_it_was_given(small_bundle, small_capture):
    from relight import load_environment
    from relight.engine.frame_path import FramePath
    from relight.engine.frame_settings import FrameSettings

    frames = _first_frames(small_capture, 6)
    env = load_environment("builtin:sunset")
    with FramePath(small_bundle, env, FrameSettings(focal="ortho", live_source=True)) as fp:
        for i, f in enumerate(frames[:6]):
            fp.process(f, i / 30)
        made = [w.name for w in fp.workers]
        assert any(_alive(n) for n in made)  # a live source's slow stages ran on them
        workers = fp.workers
    assert all(w._pool is None for w in workers)
    given = (Worker("relight-test-field", background=True), Worker("relight-test-maps", background=True))
    for w in given:  # started before the path has them
        w.submit(lambda: None).result(timeout=10)
    fp = FramePath(small_bundle, env, FrameSettings(focal="ortho", live_source=True), workers=given)
    for i, f in enumerate(frames[:6]):
        fp.process(f, i / 30)
    fp.close()
    assert all(w._pool is not None for w in given)  # the giver's to stop
    for w in given:
        w.close()
    assert not _alive("relight-test-")


def test_the_service_stops_its_workers_at_shutdown(small_bundle):
    """A real uvicorn server: the workers its stream clients share are stopped with it."""
    import uvicorn

    from relight.bench.server import free_port, wait_ready
    from relight.service.app import create_app
    from relight.service.settings import ServeConfig

    app = create_app(ServeConfig(bundle=small_bundle.path, focal="ortho"))
    port = free_port()
    srv = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    th = threading.Thread(target=srv.run, daemon=True)
    th.start()
    try:
        assert wait_ready(f"http://127.0.0.1:{port}", 60)
        workers = app.state.frame_service._workers
        for w in workers:
            w.submit(lambda: None).result(timeout=10)
        assert all(w._pool is not None for w in workers)
    finally:
        srv.should_exit = True
        th.join(timeout=20)
    assert not th.is_alive()
    assert all(w._pool is None for w in workers)
