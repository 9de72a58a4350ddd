"""Write a sequence JSON in exactly the docs/design.md §5.1 layout, byte-for-byte reproducible.

No clocks, hosts or paths go into the file; floats are written with Python's shortest round-trip
repr, so a reader gets the very same float64 values back. Two COCO details are added so pycocotools
reads the files unchanged: every annotation carries ``"iscrowd": 0`` and annotation ids start at 1
(``COCOeval`` takes id 0 for "unmatched").
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from dronekey.sim_replay.annotations import DroneAnnotation, SequenceAnnotations
from dronekey.sim_replay.io.sequence_format import N_KEYPOINTS, SKELETON

__all__ = ["dumps_sequence", "save_sequence", "sequence_to_dict"]


def _json_default(value: Any) -> Any:
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.floating):
        return float(value)
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return value.as_posix()
    raise TypeError(f"cannot write {type(value).__name__} {value!r} to a sequence JSON")


def _dump(value: Any) -> str:
    return json.dumps(value, allow_nan=False, default=_json_default, ensure_ascii=False)


def _annotation_dict(
    ann_id: int, image_id: int, drone: DroneAnnotation, frame: int, with_instance: bool
) -> dict:
    kp = np.asarray(drone.keypoints_px, dtype=np.float64)
    vis = np.asarray(drone.visibility).astype(int)
    if kp.shape != (N_KEYPOINTS, 2) or vis.shape != (N_KEYPOINTS,):
        raise ValueError(
            f"frame {frame}: keypoints must be (4, 2) with (4,) flags, got {kp.shape}, {vis.shape}"
        )
    if not drone.has_pose:
        raise ValueError(f"frame {frame}: a DroneKey sequence needs the 6DoF of every annotated drone")
    flat: list[float | int] = []
    for (u, v), flag in zip(kp.tolist(), vis.tolist(), strict=True):
        flat += [u, v, int(flag)]
    bbox = [float(x) for x in drone.bbox_xywh]
    instance = {"instance_id": int(drone.instance_id)} if with_instance else {}
    return {
        "id": ann_id,
        "image_id": image_id,
        **instance,
        "category_id": 1,
        "keypoints": flat,
        "num_keypoints": int(np.count_nonzero(vis > 0)),
        "bbox": bbox,
        "area": bbox[2] * bbox[3],
        "iscrowd": 0,
        "rotation": np.asarray(drone.rotation, dtype=np.float64).tolist(),
        "translation": np.asarray(drone.translation, dtype=np.float64).ravel().tolist(),
    }


def sequence_to_dict(seq: SequenceAnnotations) -> dict:
    """The §5.1 document of a sequence as plain Python objects (image id = frame index).

    A multi-drone sequence (``seq.instances`` given, or several instance ids) adds the top-level
    ``instances`` table and each annotation's ``instance_id``; a single-drone one is written as
    before, without either.
    """
    info = dict(seq.info)
    info.setdefault("sequence", seq.name)
    info.setdefault("fps", float(seq.fps))
    multi = bool(seq.instances) or seq.is_multi_drone
    images, annotations = [], []
    for rec in seq.frames:
        images.append(
            {
                "id": rec.index,
                "file_name": rec.file_name,
                "frame_index": rec.index,
                "timestamp_ns": int(rec.t_ns),
                "width": rec.width,
                "height": rec.height,
            }
        )
        for drone in rec.drones:
            annotations.append(_annotation_dict(len(annotations) + 1, rec.index, drone, rec.index, multi))
    instances = {}
    if multi:
        instances["instances"] = [
            {
                "instance_id": int(i),
                "model": seq.instance(i).model,
                "keypoints_3d": np.asarray(seq.instance(i).keypoints_3d).tolist(),
            }
            for i in seq.instance_ids()
        ]
    return {
        "info": info,
        "camera": seq.camera.to_dict(),
        "drone": {"model": seq.drone_model, "keypoints_3d": np.asarray(seq.keypoints_3d).tolist()},
        **instances,
        "categories": [
            {"id": 1, "name": "drone", "keypoints": list(seq.keypoint_names), "skeleton": SKELETON}
        ],
        "images": images,
        "annotations": annotations,
    }


def dumps_sequence(seq: SequenceAnnotations) -> str:
    """The JSON text of a sequence: one image or annotation per line, reproducible byte for byte.

    Raises
    ------
    ValueError
        If a value is not finite or a drone annotation lacks its pose.
    """
    doc = sequence_to_dict(seq)
    lines = ["{"]
    for i, (key, value) in enumerate(doc.items()):
        comma = "," if i < len(doc) - 1 else ""
        if key in ("images", "annotations") and value:
            lines.append(f" {_dump(key)}: [")
            lines += [f"  {_dump(item)}," for item in value[:-1]]
            lines += [f"  {_dump(value[-1])}", f" ]{comma}"]
        else:
            lines.append(f" {_dump(key)}: {_dump(value)}{comma}")
    lines.append("}")
    return "\n".join(lines) + "\n"


def save_sequence(seq: SequenceAnnotations, path: str | Path) -> None:
    """Write a sequence JSON through a temporary file renamed at the end (never a partial file)."""
    path = Path(path)
    text = dumps_sequence(seq)
    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    try:
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
