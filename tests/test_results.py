"""Per-shot results: CF-1.8 trajectory dataset, atomic NetCDF writing, chunked runs."""

from __future__ import annotations

import os

import numpy as np
import pytest
import xarray as xr

from chirplidar.mission import (
    SCHEMA,
    ChunkWriter,
    build_dataset,
    check_dataset,
    read_netcdf,
    write_netcdf,
)
from chirplidar.mission.results.schema import COMPRESSION_LEVEL

MATERIALS = {0: "snow", 1: "firn", 2: "bare ice", 3: "water"}
CONFIG = '[mission]\nname = "test"\nepsg = 3413\n[beam]\ncount = 3\n'
DATE = "2026-01-01T00:00:00Z"


def _per_shot(n_beams=3, n_shots=20, *, lat0=72.0, seed=0):
    rng = np.random.default_rng(seed)
    shape = (n_beams, n_shots)
    t = np.broadcast_to(np.arange(n_shots) * 1e-3 + 0.123456789, shape).copy()
    lat = lat0 + np.linspace(0, 0.01, n_shots)[None, :] + 0.001 * np.arange(n_beams)[:, None]
    lon = np.full(shape, -40.0) + 0.001 * np.arange(n_beams)[:, None]
    rt = 500.0 + rng.normal(0, 1, shape)
    rm = rt + rng.normal(0, 0.05, shape)
    det = rng.integers(0, 3, shape)
    rm[det != 1] = np.nan
    h_true = 2000.0 + rng.normal(0, 1, shape)
    return {
        "delta_time": t, "latitude": lat, "longitude": lon,
        "platform_x": rng.normal(0, 1e3, shape), "platform_y": rng.normal(0, 1e3, shape),
        "platform_altitude": np.full(shape, 2500.0),
        "off_nadir_angle": np.full(shape, 0.01), "azimuth_angle": rng.uniform(0, 6, shape),
        "incidence_angle": rng.uniform(0, 0.1, shape),
        "range_true": rt, "range_measured": rm, "range_error": rt - rm,
        "h_li_true": h_true, "h_li": h_true + (rm - rt),
        "snr_db": rng.normal(20, 3, shape), "received_power": 10 ** rng.normal(-9, 1, shape),
        "beat_frequency": rng.uniform(1e6, 5e7, shape), "detected": det,
        "surface_type": rng.integers(0, 4, shape),
        "footprint_diameter": np.full(shape, 0.5),
    }


def _build(per_shot=None, epsg=3413, **kw):
    args = {"epsg": epsg, "epoch_iso": "2026-01-01T00:00:00Z", "config_toml": CONFIG,
            "seed": 42, "software_version": "0.1.0", "materials": MATERIALS,
            "date_created": DATE}
    args.update(kw)
    return build_dataset(_per_shot() if per_shot is None else per_shot, **args)


def test_round_trip_identical(tmp_path):
    ds = _build()
    path = write_netcdf(ds, tmp_path / "out.nc")
    back = read_netcdf(path)
    xr.testing.assert_identical(ds, back)
    assert np.isnan(back["range_measured"].values[back["detected"].values != 1]).all()


def test_cf_structure_and_attributes(tmp_path):
    ds = _build()
    assert ds.sizes == {"trajectory": 3, "obs": 20}
    for name, var in ds.variables.items():
        assert "long_name" in var.attrs, name
        if name != "crs":
            assert "units" in var.attrs, name
    for name in ds.data_vars:
        if name != "crs":
            assert ds[name].attrs["grid_mapping"] == "crs"
    assert ds["beam"].attrs["cf_role"] == "trajectory_id"
    assert ds["time"].attrs["units"] == "seconds since 2026-01-01T00:00:00Z"
    assert ds.attrs["Conventions"] == "CF-1.8"
    assert ds.attrs["featureType"] == "trajectory"
    assert ds.attrs["configuration"] == CONFIG
    assert ds.attrs["seed"] == 42
    assert ds.attrs["source"] == "chirplidar 0.1.0"
    st = ds["surface_type"].attrs
    assert list(st["flag_values"]) == [0, 1, 2, 3]
    assert st["flag_meanings"] == "snow firn bare_ice water"
    assert ds["detected"].dtype == np.int8
    # raw file: coordinates and fill values as CF wants them
    import netCDF4
    path = write_netcdf(ds, tmp_path / "o.nc")
    with netCDF4.Dataset(path) as nc:
        coords = set(nc["h_li"].coordinates.split())
        assert {"time", "latitude", "longitude", "beam", "x", "y"} <= coords
        assert np.isnan(nc["h_li"]._FillValue)
        assert nc["h_li"].filters()["zlib"] and nc["h_li"].filters()["complevel"] == \
            COMPRESSION_LEVEL
        assert "_FillValue" not in nc["detected"].ncattrs()
        assert nc.featureType == "trajectory"


def test_x_y_from_lat_lon_match_pyproj():
    from pyproj import Transformer
    ds = _build()
    x, y = Transformer.from_crs(4326, 3413, always_xy=True).transform(
        ds["longitude"].values, ds["latitude"].values)
    np.testing.assert_allclose(ds["x"].values, x)
    np.testing.assert_allclose(ds["y"].values, y)


@pytest.mark.parametrize("epsg, lat0", [(3413, 72.0), (3031, -78.0)])
def test_grid_mapping(tmp_path, epsg, lat0):
    ds = _build(_per_shot(lat0=lat0), epsg=epsg)
    back = read_netcdf(write_netcdf(ds, tmp_path / "g.nc"))
    assert back["crs"].attrs["grid_mapping_name"] == "polar_stereographic"
    assert back["crs"].attrs["epsg_code"] == f"EPSG:{epsg}"
    assert "crs_wkt" in back["crs"].attrs
    assert back["h_li"].attrs["grid_mapping"] == "crs"


def test_no_overwrite_leaves_file_identical(tmp_path):
    path = tmp_path / "out.nc"
    write_netcdf(_build(), path)
    before = path.read_bytes()
    with pytest.raises(FileExistsError, match="out.nc"):
        write_netcdf(_build(seed=7), path)
    assert path.read_bytes() == before
    write_netcdf(_build(seed=7), path, overwrite=True)
    assert read_netcdf(path).attrs["seed"] == 7
    assert sorted(os.listdir(tmp_path)) == ["out.nc"]


@pytest.mark.parametrize("existing", [False, True])
def test_failure_mid_write_leaves_nothing(tmp_path, monkeypatch, existing):
    path = tmp_path / "out.nc"
    if existing:
        write_netcdf(_build(), path)
        before = path.read_bytes()

    def boom(self, target, *a, **k):
        with open(target, "wb") as fh:
            fh.write(b"CDF partial")
        raise OSError("disk full")

    monkeypatch.setattr(xr.Dataset, "to_netcdf", boom)
    with pytest.raises(OSError, match="disk full"):
        write_netcdf(_build(), path, overwrite=True)
    if existing:
        assert path.read_bytes() == before
        assert sorted(os.listdir(tmp_path)) == ["out.nc"]
    else:
        assert os.listdir(tmp_path) == []


def test_failure_at_fsync_leaves_nothing(tmp_path, monkeypatch):
    def boom(fd):
        raise OSError("fsync failed")

    monkeypatch.setattr(os, "fsync", boom)
    with pytest.raises(OSError, match="fsync"):
        write_netcdf(_build(), tmp_path / "out.nc")
    assert os.listdir(tmp_path) == []


def test_chunk_merge_equals_one_go(tmp_path):
    full = _per_shot(n_shots=25)
    ds = _build(full)
    cw = ChunkWriter(tmp_path / "chunks")
    bounds = [(0, 10), (10, 20), (20, 25)]
    for i, (a, b) in enumerate(bounds):
        part = {k: v[:, a:b] for k, v in full.items()}
        cw.write(i, _build(part))
    assert cw.completed_chunks() == [0, 1, 2]
    # a killed write leaves only a temp file, which is not a completed chunk
    (cw.path_dir / ".chunk_00003.nc.abc.tmp").write_bytes(b"partial")
    assert cw.completed_chunks() == [0, 1, 2]
    assert len(cw.remove_temporaries()) == 1
    with pytest.raises(FileExistsError):
        cw.write(1, _build({k: v[:, 10:20] for k, v in full.items()}))
    merged = cw.merge(tmp_path / "final.nc")
    xr.testing.assert_identical(merged, ds)
    xr.testing.assert_identical(read_netcdf(tmp_path / "final.nc"), ds)
    with pytest.raises(ValueError, match="missing"):
        cw.merge(tmp_path / "final2.nc", n_chunks=4)
    with pytest.raises(FileExistsError):
        cw.merge(tmp_path / "final.nc")


def _file_header(path):
    """Dimensions, variables (dtype, dims, filters, chunking, attributes), global attributes."""
    import netCDF4

    with netCDF4.Dataset(path) as d:
        out = [("dims", [(k, len(v)) for k, v in d.dimensions.items()]),
               ("attrs", [(k, repr(d.getncattr(k))) for k in d.ncattrs()])]
        for name, v in d.variables.items():
            out.append((name, str(v.dtype), v.dimensions, v.filters(), v.chunking(),
                        [(k, repr(v.getncattr(k))) for k in v.ncattrs()]))
    return out


def test_incremental_merge_in_any_completion_order(tmp_path):
    """Chunks appended as they appear (out of order: each waits for the ones before it) give
    write_netcdf's file of the whole dataset with the same HDF5 chunking (a chunk of obs per
    HDF5 chunk); merge_to_file gives the same file."""
    full = _per_shot(n_shots=29)
    ds = _build(full)
    cw = ChunkWriter(tmp_path / "chunks")
    bounds = [(0, 10), (10, 20), (20, 29)]
    merge = cw.start_merge(tmp_path / "inc.nc", [b - a for a, b in bounds], obs_chunk=10)
    assert merge.append_ready() == 0                    # nothing yet
    for i in (2, 1):                                    # chunk 0 last: nothing can be appended
        a, b = bounds[i]
        cw.write(i, _build({k: v[:, a:b] for k, v in full.items()}), compress=False)
        assert merge.append_ready() == 0 and not (tmp_path / "inc.nc").exists()
    cw.write(0, _build({k: v[:, :10] for k, v in full.items()}), compress=False)
    assert merge.append_ready() == 3
    assert merge.finish() == tmp_path / "inc.nc"
    write_netcdf(ds, tmp_path / "whole.nc", obs_chunk=10)
    cw.merge_to_file(tmp_path / "merged.nc", obs_chunk=10)
    for p in ("inc.nc", "merged.nc"):
        xr.testing.assert_identical(read_netcdf(tmp_path / p), ds)
        assert _file_header(tmp_path / p) == _file_header(tmp_path / "whole.nc")
    import netCDF4

    with netCDF4.Dataset(tmp_path / "inc.nc") as d:
        assert d["range_true"].chunking() == [3, 10]
        assert d["detected"].chunking() == "contiguous"
    assert sorted(os.listdir(tmp_path)) == ["chunks", "inc.nc", "merged.nc", "whole.nc"]


def _stored_chunks(path, name):
    """(offset, filter mask, compressed bytes) of every HDF5 chunk of variable ``name``."""
    import h5py

    with h5py.File(path, "r") as f:
        d = f[name].id
        return [(i.chunk_offset, *d.read_direct_chunk(i.chunk_offset))
                for i in (d.get_chunk_info(k) for k in range(d.get_num_chunks()))]


def _spy_copies(monkeypatch):
    """Record (variable, chunk start, copied raw?) of every variable the merge copies."""
    from chirplidar.mission.results import merge

    calls = []
    copy = merge._copy_hdf5_variable

    def spy(src, dst, axis, start, last, record=None):
        import h5py

        out = copy(src, dst, axis, start, last, record)
        calls.append((h5py.h5i.get_name(src[0]).decode().lstrip("/"), start, out is None))
        return out

    monkeypatch.setattr(merge, "_copy_hdf5_variable", spy)
    return calls


def test_merge_copies_compressed_chunks_as_stored(tmp_path, monkeypatch):
    """Chunks written with the merge's obs_chunk (a run's chunk files) are copied into the
    results file as their compressed HDF5 chunks, byte for byte -- the short last chunk too
    (stored full-size along an unlimited obs) -- and the file is write_netcdf's of the whole
    dataset with that obs_chunk (reference)."""
    calls = _spy_copies(monkeypatch)
    full = _per_shot(n_shots=27)
    ds = _build(full)
    cw = ChunkWriter(tmp_path / "chunks")
    bounds = [(0, 10), (10, 20), (20, 27)]
    files = [cw.write(i, _build({k: v[:, a:b] for k, v in full.items()}), obs_chunk=10)
             for i, (a, b) in enumerate(bounds)]
    import netCDF4

    with netCDF4.Dataset(files[2]) as d:          # the short one: obs unlimited, 1 HDF5 chunk
        assert d.dimensions["obs"].isunlimited() and d["range_true"].chunking() == [3, 10]
    cw.merge_to_file(tmp_path / "merged.nc", obs_chunk=10)
    write_netcdf(ds, tmp_path / "whole.nc", obs_chunk=10)
    xr.testing.assert_identical(read_netcdf(tmp_path / "merged.nc"), ds)
    assert _file_header(tmp_path / "merged.nc") == _file_header(tmp_path / "whole.nc")
    for name in ("range_true", "snr_db", "delta_time"):
        got = _stored_chunks(tmp_path / "merged.nc", name)
        want = [((o[0], o[1] + a), m, raw) for (a, _), f in zip(bounds, files)
                for o, m, raw in _stored_chunks(f, name)]
        assert got == want, name
    # compressed (float) variables copied as stored, the uncompressed integer flags as values
    floats = {k for k, v in ds.variables.items() if v.dtype.kind == "f"}
    assert {(name, start, name in floats) for name, start, _ in calls} == set(calls)
    assert {start for _, start, _ in calls} == {0, 10, 20}


def test_merge_of_chunks_off_the_chunk_grid(tmp_path, monkeypatch):
    """Chunk files whose HDF5 chunks do not fit the results file's (a chunk longer than
    obs_chunk, another starting off its grid, others uncompressed or chunked otherwise) are
    decompressed and compressed again: the same file as write_netcdf's of the whole."""
    calls = _spy_copies(monkeypatch)
    full = _per_shot(n_shots=29)
    ds = _build(full)
    cw = ChunkWriter(tmp_path / "chunks")
    bounds = [(0, 12), (12, 20), (20, 25), (25, 29)]
    for i, (a, b) in enumerate(bounds):
        part = _build({k: v[:, a:b] for k, v in full.items()})
        cw.write(i, part, **({"compress": False} if i == 2 else {"obs_chunk": (10, 10, 10, 3)[i]}))
    cw.merge_to_file(tmp_path / "merged.nc", obs_chunk=10)
    write_netcdf(ds, tmp_path / "whole.nc", obs_chunk=10)
    xr.testing.assert_identical(read_netcdf(tmp_path / "merged.nc"), ds)
    assert _file_header(tmp_path / "merged.nc") == _file_header(tmp_path / "whole.nc")
    assert calls and not any(raw for _, _, raw in calls)   # no chunk fits the grid


def test_incremental_merge_errors_leave_nothing(tmp_path):
    full = _per_shot(n_shots=20)
    cw = ChunkWriter(tmp_path / "chunks")
    cw.write(0, _build({k: v[:, :10] for k, v in full.items()}))
    with pytest.raises(ValueError, match=r"missing.*\[1\]"), \
            cw.start_merge(tmp_path / "a.nc", [10, 10]) as merge:
        merge.finish()
    with pytest.raises(ValueError, match="chunk 0 .*10 observations, expected 12"), \
            cw.start_merge(tmp_path / "b.nc", [12, 8]) as merge:
        merge.append_ready()
    cw.write(1, _build({k: v[:, 10:] for k, v in full.items()}, seed=7))
    with pytest.raises(ValueError, match=r"chunk 1 .*global attributes \[.*'seed'\] differ"), \
            cw.start_merge(tmp_path / "c.nc", [10, 10]) as merge:
        merge.finish()
    with pytest.raises(ValueError, match="obs_chunk"):
        cw.start_merge(tmp_path / "d.nc", [10, 10], obs_chunk=0)
    with pytest.raises(ValueError, match="obs_chunk"):
        write_netcdf(_build(), tmp_path / "e.nc", obs_chunk=2.5)
    assert sorted(os.listdir(tmp_path)) == ["chunks"]   # no results file, no temp file


def test_chunk_merge_missing_chunk(tmp_path):
    cw = ChunkWriter(tmp_path)
    cw.write(0, _build())
    cw.write(2, _build())
    with pytest.raises(ValueError, match=r"missing.*\[1\]"):
        cw.merge(tmp_path / "final.nc")
    assert not (tmp_path / "final.nc").exists()


def test_zero_shots(tmp_path):
    ds = _build(_per_shot(n_shots=0))
    assert ds.sizes == {"trajectory": 3, "obs": 0}
    back = read_netcdf(write_netcdf(ds, tmp_path / "empty.nc"))
    xr.testing.assert_identical(ds, back)
    check_dataset(back)


def test_flat_layout_matches_2d():
    full = _per_shot(n_beams=2, n_shots=5)
    ds = _build(full)
    flat = {k: v.T.reshape(-1) for k, v in full.items()}  # shots interleaved across beams
    flat["beam"] = np.tile([0, 1], 5)
    xr.testing.assert_identical(_build(flat), ds)
    flat["beam"] = np.array([0] * 6 + [1] * 4)
    with pytest.raises(ValueError, match="same number of shots"):
        _build(flat)


def test_minimal_input_xy_only():
    ds = _build({"delta_time": np.zeros((1, 2)), "x": np.array([[0.0, 1e5]]),
                 "y": np.array([[-1e6, -1e6]])}, materials=None)
    assert np.all(ds["latitude"].values > 60)
    assert set(ds.data_vars) == {"crs"}


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d.update(bogus=d["h_li"]), "bogus"),
    (lambda d: d.update(h_li=d["h_li"][:, :3]), "h_li"),
    (lambda d: d.update(detected=d["detected"] + 5), "detected"),
    (lambda d: d.update(surface_type=d["surface_type"] + 10), "surface_type"),
    (lambda d: d.update(snr_db=np.full_like(d["snr_db"], np.inf)), "snr_db"),
    (lambda d: d.update(time=d["delta_time"]), "time"),
    (lambda d: d.pop("delta_time"), "delta_time"),
    (lambda d: d["delta_time"].__setitem__((0, 0), np.nan), "delta_time"),
    (lambda d: d.pop("longitude"), "longitude"),
])
def test_bad_input_names_variable(mutate, match):
    d = _per_shot()
    mutate(d)
    with pytest.raises(ValueError, match=match):
        _build(d)


@pytest.mark.parametrize("kw, match", [
    ({"epsg": 4326}, "epsg"), ({"epsg": "3413"}, "epsg"),
    ({"epoch_iso": "yesterday"}, "epoch_iso"), ({"config_toml": "a = ["}, "config_toml"),
    ({"seed": 1.5}, "seed"), ({"materials": {"a": "snow"}}, "materials"),
])
def test_bad_arguments(kw, match):
    with pytest.raises(ValueError, match=match):
        _build(**kw)


def test_check_dataset_requires_units_and_long_name():
    ds = _build()
    ds["h_li"].attrs.pop("units")
    with pytest.raises(ValueError, match="h_li"):
        check_dataset(ds)
    ds = _build()
    ds["snr_db"].attrs.pop("long_name")
    with pytest.raises(ValueError, match="snr_db"):
        write_netcdf(ds, "never.nc")


def test_schema_table_complete():
    names = [s.name for s in SCHEMA]
    assert len(names) == len(set(names))
    for s in SCHEMA:
        assert s.units and s.long_name
    assert {"delta_time", "latitude", "longitude", "h_li"} <= {
        s.icesat2_name for s in SCHEMA if s.icesat2_name}
