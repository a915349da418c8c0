"""The frame service: frames relit over HTTP, websocket and WebRTC with a loaded bundle (FastAPI;
``relight serve`` / ``relight-serve``), and its browser page."""
