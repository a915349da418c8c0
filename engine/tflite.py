"""The small models shipped inside the package (``engine/models/<name>/``: the file, its licence
and a ``model.json`` manifest with its sha256 and source) and their OpenCV networks, run by
OpenCV's TFLite importer on the CPU. Loaded from the package, never fetched."""

from __future__ import annotations

import json
from pathlib import Path

import cv2

from relight.errors import InputError


def manifest(model_dir: Path) -> dict:
    """The shipped model's manifest (``model_dir/model.json``)."""
    return json.loads((Path(model_dir) / "model.json").read_text())


def load_net(model_dir: Path, what: str):
    """The ``cv2.dnn`` network of the model shipped in ``model_dir`` (``what`` names it in the
    error when its file is missing)."""
    path = Path(model_dir) / manifest(model_dir)["file"]
    if not path.is_file():
        raise InputError(f"{path}: the {what} model is missing; reinstall relight")
    net = cv2.dnn.readNetFromTFLite(str(path))
    net.setPreferableBackend(cv2.dnn.DNN_BACKEND_OPENCV)
    net.setPreferableTarget(cv2.dnn.DNN_TARGET_CPU)
    return net
