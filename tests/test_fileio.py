"""raytrace.core.fileio: YAML reading with YAML 1.2 numbers and one-line errors."""

from __future__ import annotations

import pytest

from raytrace.core.errors import HallrayError, MaterialError
from raytrace.core.fileio import read_yaml
from raytrace.physics.materials import MaterialLibrary


def test_yaml_numbers_follow_yaml_1_2(tmp_path):
    f = tmp_path / "n.yaml"
    f.write_text("a: 1.0e9\nb: 1e-3\nc: .5\nd: -2E+3\ne: 12\nf: true\ng: 1.2.3\nh: '1.0e9'\n")
    got = read_yaml(f, "numbers")
    assert got == {"a": 1e9, "b": 1e-3, "c": 0.5, "d": -2e3, "e": 12, "f": True, "g": "1.2.3",
                   "h": "1.0e9"}  # fmt: skip
    assert isinstance(got["a"], float) and isinstance(got["e"], int)


def test_byte_order_mark_and_one_line_errors(tmp_path):
    f = tmp_path / "bom.yaml"
    f.write_bytes("\ufeffx: 1\n".encode())
    assert read_yaml(f, "file") == {"x": 1}
    with pytest.raises(HallrayError, match=r"^cannot read test file: not found: .*nope\.yaml$"):
        read_yaml(tmp_path / "nope.yaml", "test file")
    bad = tmp_path / "bad.yaml"
    bad.write_text("a: [1, 2\nb: 3\n")
    with pytest.raises(MaterialError, match="invalid YAML at line") as err:
        read_yaml(bad, "material file", MaterialError)
    assert "\n" not in str(err.value)
    latin = tmp_path / "latin.yaml"
    latin.write_bytes(b"name: caf\xe9\n")
    with pytest.raises(HallrayError, match="cannot read file .*latin.yaml"):
        read_yaml(latin, "file")


def test_a_user_material_with_an_exponent_is_a_number(tmp_path):
    f = tmp_path / "m.yaml"
    f.write_text("materials:\n  ferrite: {eta_real: 1.2e1, sigma: 1.0e-2, thickness: 5.0e-3}\n")
    mat = MaterialLibrary.itu().with_yaml(f)["ferrite"]
    assert (mat.a, mat.c, mat.thickness_m) == (12.0, 0.01, 0.005)
