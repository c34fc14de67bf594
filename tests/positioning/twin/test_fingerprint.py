"""Fingerprint map file: round trip, schema checks with one-line errors."""

from __future__ import annotations

import numpy as np
import pytest

from positioning import PositioningError
from positioning.twin.fingerprint import SCHEMA_VERSION, FingerprintMap, read_map, write_map


def _map(n: int = 6, b: int = 4, m: int = 2) -> FingerprintMap:
    rng = np.random.default_rng(3)
    return FingerprintMap(
        cell_xyz=rng.uniform(0, 10, (n, 3)),
        bs_xyz=rng.uniform(0, 10, (b, 3)),
        bs_names=np.array([f"BS{i + 1}" for i in range(b)]),
        los=rng.random((n, b)) < 0.7,
        first_kind=np.full((n, b), "LoS"),
        excess_m=np.zeros((n, b)),
        toa_s=rng.uniform(1e-8, 1e-7, (n, b)),
        toa_std_s=np.full((n, b), 1e-10),
        detected_fraction=np.ones((n, b)),
        gdop=rng.uniform(1, 3, n),
        methods=np.array(["ls", "irls"][:m]),
        err_p90_m=rng.random((m, n)),
        err_mean_m=rng.random((m, n)),
        availability=np.ones((m, n)),
        meta={"band": "C-band", "step_m": 2.0, "service_area": [[0, 0], [10, 0], [10, 10]]},
    )


def test_round_trip_is_exact(tmp_path):
    fmap = _map()
    path = write_map(tmp_path / "map.npz", fmap)
    back = read_map(path)
    for key, arr in fmap.arrays().items():
        np.testing.assert_array_equal(getattr(back, key), arr, err_msg=key)
    assert back.meta == fmap.meta
    assert back.n_cells == 6 and back.n_bs == 4
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left


def test_inconsistent_shape_refused():
    with pytest.raises(PositioningError, match="toa_s"):
        fm = _map()
        FingerprintMap(**{**fm.arrays(), "toa_s": np.zeros((5, 4))}, meta={})


@pytest.mark.parametrize(
    "change, match",
    [
        ({"schema": np.array("something-else")}, "not a hallray-accuracy-map file"),
        ({"schema_version": np.array(SCHEMA_VERSION + 97)}, "version 99 is not supported"),
        ({"gdop": np.zeros(3)}, "gdop"),
        ({"meta_json": np.array("{oops")}, "meta_json"),
    ],
)
def test_mismatched_map_refused(tmp_path, change, match):
    path = write_map(tmp_path / "map.npz", _map())
    with np.load(path) as z:
        data = {k: z[k] for k in z.files}
    data.update(change)
    np.savez(path, **data)
    with pytest.raises(PositioningError, match=match) as info:
        read_map(path)
    assert "\n" not in str(info.value)


def test_missing_key_and_corrupt_file_refused(tmp_path):
    path = write_map(tmp_path / "map.npz", _map())
    with np.load(path) as z:
        data = {k: z[k] for k in z.files if k != "los"}
    np.savez(path, **data)
    with pytest.raises(PositioningError, match="missing array 'los'"):
        read_map(path)
    good = write_map(tmp_path / "good.npz", _map())
    cut = tmp_path / "cut.npz"
    cut.write_bytes(good.read_bytes()[:200])
    with pytest.raises(PositioningError, match="cut.npz"):
        read_map(cut)
    with pytest.raises(PositioningError, match="no such map file"):
        read_map(tmp_path / "absent.npz")


RECEIVER_MODEL = {"frequency_hz": 3.5e9, "period_s": 1.25e-8, "roll_off": 0.25,
                  "oversampling": 8, "span": 16, "noise_std": 1e-2, "alpha": 13.8,
                  "rho": 0.25}  # fmt: skip


def _map_v2(n: int = 6, b: int = 4, k: int = 3) -> FingerprintMap:
    rng = np.random.default_rng(4)
    base = _map(n, b)
    u = rng.normal(size=(n, b, k, 3))
    delay = rng.uniform(1e-8, 1e-7, (n, b, k))
    delay[0, 0, 2] = np.nan  # a padded slot
    gain = rng.normal(size=(n, b, k)) + 1j * rng.normal(size=(n, b, k))
    gain[0, 0, 2] = 0.0
    return FingerprintMap(
        **base.arrays(), meta={**base.meta, "receiver_model": RECEIVER_MODEL},
        path_delay_s=delay, path_gain=gain, path_dir=u / np.linalg.norm(u, axis=3, keepdims=True),
        path_radius_m=rng.uniform(1, 40, (n, b, k)),
    )  # fmt: skip


def test_v1_and_v2_round_trip(tmp_path):
    """A map without paths is written as version 1 and one with paths as version 2; both read
    back exactly, and the version-1 map has no paths."""
    for fmap, version in ((_map(), 1), (_map_v2(), 2)):
        path = write_map(tmp_path / f"v{version}.npz", fmap)
        with np.load(path) as z:
            assert int(z["schema_version"]) == version
        back = read_map(path)
        assert back.version == version and back.has_paths == (version == 2)
        for key, arr in fmap.arrays().items():
            np.testing.assert_array_equal(getattr(back, key), arr, err_msg=key)
        assert back.meta == fmap.meta


@pytest.mark.parametrize(
    "change, match",
    [
        ({"path_gain": None}, "schema version 2 needs array 'path_gain'"),
        ({"path_dir": np.zeros((6, 4, 2, 3))}, "'path_dir' has shape"),
        ({"path_delay_s": np.zeros((6, 4, 3), dtype=complex)}, "'path_delay_s' has dtype"),
        ({"meta_json": np.array('{"band": "C-band"}')}, "receiver model: meta"),
    ],
)
def test_corrupt_v2_map_refused_in_one_line(tmp_path, change, match):
    path = write_map(tmp_path / "map.npz", _map_v2())
    with np.load(path) as z:
        data = {k: z[k] for k in z.files}
    for key, value in change.items():
        if value is None:
            del data[key]
        else:
            data[key] = value
    np.savez(path, **data)
    with pytest.raises(PositioningError, match=match) as info:
        read_map(path)
    assert "\n" not in str(info.value)
