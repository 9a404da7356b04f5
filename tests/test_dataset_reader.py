"""The torch reader (unwrap.dataset.FringeOrderDataset): schema check, the item interface of
docs/dataset.md, priors from unwrap's own decoders, crops/flips, DataLoader
workers under fork and spawn, and real captures through the same reader."""
import math

import h5py
import numpy as np
import pytest
import torch

from synth.export.dataset import export_dataset
from unwrap.dataset import FringeOrderDataset, open_dataset
from unwrap.dataset_schema import DatasetSchemaError, decode_phase, encode_phase
from unwrap.errors import UnwrapError
from unwrap.temporal import mf_unwrap, mw_unwrap, nt_unwrap

from conftest import shared_data
from dataset_helpers import tiny_config

KEYS = {"prior": ((1,), torch.float32), "phase_low": ((1,), torch.float32), "phase_high": ((1,), torch.float32),
        "modulation_low": ((1,), torch.float32), "modulation_high": ((1,), torch.float32),
        "order_traditional": ((), torch.int64), "order_true": ((), torch.int64), "valid": ((), torch.bool)}


@pytest.fixture(scope="module")
def twin_file(tmp_path_factory):
    d = tmp_path_factory.mktemp("twin")
    cfg = tiny_config(d, samples=3, frequencies="[1, 15, 16]", steps=6,
                      effects="noise = {full_well_e = 1500, read_noise_e = 4}")
    export_dataset(cfg, d / "d.h5", progress=False)
    return d / "d.h5"


def test_phase_encoding_round_trips_within_half_a_count():
    phi = np.linspace(-math.pi, math.pi, 10001)
    back = decode_phase(encode_phase(phi))
    err = np.angle(np.exp(1j * (back - phi)))
    assert np.abs(err).max() <= 0.5 * math.pi / 32768 + 1e-15
    assert back.min() >= -math.pi and back.max() < math.pi


@pytest.mark.parametrize("method, freqs", [("mf", (1, 16)), ("mw", (15, 16)), ("nt", (15, 16))])
def test_item_has_the_contract_keys_shapes_and_dtypes_and_no_nan(twin_file, method, freqs):
    ds = FringeOrderDataset(twin_file, method=method, frequencies=freqs)
    assert len(ds) == 3 and ds.available_frequencies == [1.0, 15.0, 16.0]
    assert ds.attrs["schema_version"] == 1 and "system" in ds.attrs and "config" in ds.attrs
    item = ds[1]
    H, W = 120, 160
    for k, (lead, dtype) in KEYS.items():
        assert item[k].dtype == dtype and tuple(item[k].shape) == lead + (H, W), k
        if dtype == torch.float32:
            assert torch.isfinite(item[k]).all(), k
    assert item["frequency_low"].dtype == torch.float64 and float(item["frequency_high"]) == freqs[1]
    assert int(item["index"]) == 1 and bool(item["has_reference"])
    v = item["valid"]
    assert v.float().mean() > 0.05
    for k in ("prior", "phase_low", "phase_high", "modulation_low"):
        assert (item[k][0][~v] == 0).all()
    assert (item["order_traditional"][~v] == -1).all() and (item["order_true"][~v] == -1).all()
    assert item["order_traditional"][v].min() >= 0 and item["order_traditional"][v].max() <= 16
    assert item["phase_high"].abs().max() <= math.pi


def test_prior_and_traditional_order_are_unwraps_own_on_the_stored_phases(twin_file):
    with h5py.File(twin_file, "r") as h5:
        ph = decode_phase(h5["v/phase"][2])            # (F, H, W)
        flags = h5["v/flags"][2]
        lit = (h5["masks"][2] & 2) != 0
    valid = lit & (flags[[0, 2]] == 0).all(0)
    ds = FringeOrderDataset(twin_file, method="mf", frequencies=(1, 16))
    item = ds[2]
    assert torch.equal(item["valid"], torch.from_numpy(valid))
    r = mf_unwrap([ph[0], ph[2]], (1, 16), width=912, valid=valid)
    np.testing.assert_array_equal(item["order_traditional"].numpy()[r.valid], r.order[r.valid])
    np.testing.assert_allclose(item["prior"][0].numpy()[valid], r.prior[valid].astype(np.float32), rtol=0, atol=0)
    valid = lit & (flags[[1, 2]] == 0).all(0)      # the mw / nt pair (15, 16)
    r = mw_unwrap([ph[1], ph[2]], (15, 16), width=912, valid=valid)
    np.testing.assert_array_equal(FringeOrderDataset(twin_file, method="mw", frequencies=(15, 16))[2]
                                  ["order_traditional"].numpy()[r.valid], r.order[r.valid])
    r = nt_unwrap([ph[1], ph[2]], (15, 16), width=912, valid=valid)
    item = FringeOrderDataset(twin_file, method="nt", frequencies=(15, 16))[2]
    np.testing.assert_array_equal(item["order_traditional"].numpy()[r.valid], r.order[r.valid])


def test_true_order_makes_the_measured_phase_absolute_and_mostly_equals_the_geometric_order(twin_file):
    ds = FringeOrderDataset(twin_file, method="mf", frequencies=(1, 16))
    with h5py.File(twin_file, "r") as h5:
        geometric = h5["v/order"][0, 2].astype(np.int64)
        coord = h5["v/coordinate"][0].astype(np.float64)
    item = ds[0]
    v = item["valid"].numpy()
    k = item["order_true"].numpy()
    Phi = 2 * math.pi * 16 * coord / 912
    err = Phi - (item["phase_high"][0].numpy().astype(np.float64) + 2 * math.pi * k)
    assert np.abs(err[v]).max() < 0.5            # noise, far below pi: the order is the right one
    same = (k == geometric)[v].mean()
    assert 0.9 < same < 1.0                      # differs only where noise crossed the wrap cut


def test_crops_and_flips_are_fixed_per_seed_epoch_and_index_and_consistent(twin_file):
    ds = FringeOrderDataset(twin_file, frequencies=(1, 16), crop=(64, 96), flip=True, seed=3)
    a, b = ds[1], ds[1]
    assert all(torch.equal(a[k], b[k]) for k in KEYS) and a["prior"].shape == (1, 64, 96)
    ds.set_epoch(1)
    c = ds[1]
    assert not torch.equal(a["prior"], c["prior"])
    # a crop/flip moves every map together: the traditional order still follows from the prior
    for it in (a, c):
        v = it["valid"]
        assert torch.equal(it["order_traditional"][v], torch.ceil(it["prior"][0][v].double() - 0.5 - 1e-9).long().clamp(0, 16))
    with pytest.raises(UnwrapError, match="crop"):
        FringeOrderDataset(twin_file, frequencies=(1, 16), crop=(500, 10))


@pytest.mark.parametrize("context", ["fork", "spawn"])
def test_dataloader_with_two_workers_gives_the_same_batches_as_the_main_process(twin_file, context):
    ds = FringeOrderDataset(twin_file, frequencies=(1, 16), crop=(48, 64), flip=True, seed=5)
    ds[0]  # a handle opened in the parent must not reach the workers
    ref = [b["prior"] for b in torch.utils.data.DataLoader(ds, batch_size=2, num_workers=0)]
    got = [b["prior"] for b in torch.utils.data.DataLoader(ds, batch_size=2, num_workers=2,
                                                           multiprocessing_context=context)]
    assert len(ref) == len(got) == 2 and all(torch.equal(x, y) for x, y in zip(ref, got))


def test_reader_refuses_foreign_files_versions_pairs_and_subsets_clearly(twin_file, tmp_path):
    foreign = tmp_path / "foreign.h5"
    with h5py.File(foreign, "w") as h5:
        h5["x"] = np.zeros(3)
    with pytest.raises(DatasetSchemaError, match="not a fringe-order dataset"):
        FringeOrderDataset(foreign)
    newer = tmp_path / "newer.h5"
    newer.write_bytes(twin_file.read_bytes())
    with h5py.File(newer, "r+") as h5:
        h5.attrs["schema_version"] = 99
    with pytest.raises(DatasetSchemaError, match="schema version 99"):
        FringeOrderDataset(newer)
    (tmp_path / "text.h5").write_text("hello")
    with pytest.raises(DatasetSchemaError, match="not a readable HDF5"):
        FringeOrderDataset(tmp_path / "text.h5")
    for kw, msg in ((dict(frequencies=(1, 48)), r"frequencies \['48'\] not in the file"),
                    (dict(method="mw", frequencies=(1, 16)), "beat 15 periods exceeds 1"),
                    (dict(method="nt", frequencies=(15, 30)), "coprime"),
                    (dict(method="mf", frequencies=(15, 16)), "unit frequency"),
                    (dict(orientation="h"), "not 'h'"), (dict(samples=[0, 3], frequencies=(1, 16)), r"\[0, 3\)")):
        with pytest.raises(UnwrapError, match=msg):
            FringeOrderDataset(twin_file, **kw)
    ds = open_dataset([twin_file, twin_file], samples=[4, 5], frequencies=(1, 16))
    assert len(ds) == 2 and int(ds[0]["index"]) == 4


@pytest.mark.realdata
def test_real_skull_capture_reads_through_the_same_reader_with_its_point_cloud_reference(tmp_path):
    from synth.export.capture import export_capture

    root = shared_data("slstudio-ps2x3-calib")
    s = export_capture(root / "skull_2x3", tmp_path / "skull.h5",
                       reference_cloud=root / "skull_reference" / "pointCloud_from_skull_gray.mat",
                       reference_system=root / "calibration" / "calibration.xml")
    st = s["captures"][0]["orientations"]["v"]["f16"]
    assert st["pixels_with_reference"] > 80_000 and st["margin_p99_periods"] < 0.1
    item = FringeOrderDataset(tmp_path / "skull.h5", method="mf", frequencies=(1, 16))[0]
    ref = item["order_true"] >= 0
    assert bool(item["has_reference"]) and ref.sum() > 80_000
    err = (item["order_traditional"][ref] != item["order_true"][ref]).float().mean()
    assert err < 0.02


@pytest.mark.realdata
def test_real_slmaster_capture_gray_reference_equals_unwraps_gray_decode(tmp_path):
    from synth.export.capture import export_capture
    from unwrap.pipeline import unwrap_capture

    root = shared_data("slmaster-monocular-12step-cgc")
    export_capture(root, tmp_path / "slm.h5")
    r = unwrap_capture(root, "gray")["v"].result
    with h5py.File(tmp_path / "slm.h5", "r") as h5:
        ref = h5["v/reference_order"][0, 0]
        assert list(h5["v"].attrs["frequencies"]) == [32.0]
    assert (ref >= 0).sum() > 200_000
    # the export's reference is computed from the phase as stored (int16 steps), unwrap's decode from
    # float64: a pixel within a storage step of a fringe boundary may round the other way (1 of
    # 205,584 under OPENBLAS_CORETYPE=SkylakeX, 0 under the default kernel) - by one order at most
    diff = ref[ref >= 0].astype(np.int64) - r.order[ref >= 0]
    assert np.count_nonzero(diff) <= 5 and np.abs(diff).max() <= 1, (np.count_nonzero(diff), np.abs(diff).max())
    with pytest.raises(UnwrapError, match="not in the file"):
        FringeOrderDataset(tmp_path / "slm.h5", method="mf", frequencies=(1, 32))
