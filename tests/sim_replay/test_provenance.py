"""A sequence says which renderer drew it: the simulator's source and the libraries that draw."""

import json
import re

from dronekey.sim_replay import provenance
from dronekey.sim_replay.io.render_output import write_sequence
from dronekey.sim_replay.provenance import renderer_fingerprint
from dronekey.sim_replay.synthetic_sequence import build_sequence


def test_the_fingerprint_names_the_source_and_the_drawing_libraries():
    fingerprint = renderer_fingerprint()
    assert re.match(
        r"source [0-9a-f]{12}; av \S+; libavcodec \d+\.\d+\.\d+; opencv-python-headless ", fingerprint
    )
    assert "numpy " in fingerprint and "scikit-image " in fingerprint and "scikit-learn " in fingerprint
    assert provenance._source_digest() == fingerprint.split(";")[0].removeprefix("source ")  # stable


def test_the_source_digest_follows_every_simulator_file(tmp_path, monkeypatch):
    (tmp_path / "a.py").write_text("x = 1\n")
    (tmp_path / "io").mkdir()
    (tmp_path / "io" / "b.py").write_text("y = 2\n")
    monkeypatch.setattr(provenance, "_SOURCE_ROOT", tmp_path)
    before = provenance._source_digest()
    (tmp_path / "io" / "b.py").write_text("y = 3\n")
    assert provenance._source_digest() != before


def test_a_written_sequence_carries_it(tmp_path):
    seq = build_sequence("seq13", seed=3, frames=2, width=160, height=90)
    assert seq.info["renderer"] == renderer_fingerprint()
    written = write_sequence(seq, tmp_path)
    assert json.loads(written.json_path.read_text())["info"]["renderer"] == renderer_fingerprint()
