"""Every description goes through the one strict reader (unwrap.strict): the training and export
configs round-trip through their TOML (defaults and every shipped config, ``inf`` included), and
unknown keys / wrong types are refused naming the closest key / the expected type."""
import dataclasses
from pathlib import Path

import pytest
import tomli_w

from synth.export.config import ExportConfigError, config_from_dict, load_config
from unwrap.learned.config import TrainConfig, resolve_config, to_toml
from unwrap.learned.errors import ConfigError
from unwrap.strict import check_table, from_table, schema_of, to_table

REPO = Path(__file__).resolve().parents[1]
SHIPPED_TRAIN = sorted((REPO / "unwrap" / "learned" / "data").rglob("*.toml"))
SHIPPED_EXPORT = sorted((REPO / "synth" / "data").glob("export_*.toml"))


def test_there_are_shipped_configs_to_check():
    assert len(SHIPPED_TRAIN) >= 2 and len(SHIPPED_EXPORT) >= 2


def test_the_training_defaults_round_trip_through_toml():
    cfg = TrainConfig()
    assert from_table(TrainConfig, to_table(cfg), "defaults", ConfigError) == cfg
    assert resolve_config(None, ["data.synthetic_samples=0", "data.train=['x.h5']"]).data.train == ("x.h5",)


@pytest.mark.parametrize("path", SHIPPED_TRAIN, ids=lambda p: p.name)
@pytest.mark.parametrize("grad_clip", [None, "inf"])
def test_every_shipped_training_config_round_trips(path, grad_clip, tmp_path):
    # the fine-tuning config names its captures on the command line (its header): give it one
    data = ["data.train=['cap_a.h5']"] if path.name == "finetune_real.toml" else []
    cfg = resolve_config(path, data + ([f"optim.grad_clip={grad_clip}"] if grad_clip else []))
    (tmp_path / "config.toml").write_text(to_toml(cfg))
    back = resolve_config(tmp_path / "config.toml")
    assert back == cfg and dataclasses.is_dataclass(back)
    with pytest.raises(dataclasses.FrozenInstanceError):
        back.optim.steps = 3


@pytest.mark.parametrize("path", SHIPPED_EXPORT, ids=lambda p: p.name)
def test_every_shipped_export_config_round_trips(path):
    cfg = load_config(path)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.samples = 3
    import tomllib
    tree = tomllib.loads(path.read_text())
    again = config_from_dict(tomllib.loads(tomli_w.dumps(tree)), path.parent, cfg.text)
    assert again == cfg
    assert load_config(path, ["export.samples=7"]).samples == 7


@pytest.mark.parametrize("bad, message", [
    (["optim.steps=4.0"], "optim.steps = 4.0: expected an integer, got a float"),
    (['optim.steps="4"'], "optim.steps = '4': expected an integer, got a string"),
    (["optim.stpes=4"], "did you mean 'optim.steps'"),
    (["optimm.steps=4"], r"unknown section \[optimm\] \(did you mean \[optim\]\?\)"),
    (["data.methods=['mf', 3]"], "expected an array of strings"),
    (["run.amp=1"], "expected a boolean"),
])
def test_training_config_refusals_name_the_key_and_the_type(bad, message):
    with pytest.raises(ConfigError, match=message):
        resolve_config(None, bad + ["data.synthetic_samples=4"])


@pytest.mark.parametrize("doc, message", [
    ({"export": {"samples": 3}, "patterns": {"steps": 4.0}}, "patterns.steps = 4.0: expected an integer"),
    ({"export": {"samples": 3}, "patterns": {"steps": "4"}}, "patterns.steps = '4': expected an integer"),
    ({"export": {"samples": 3, "sed": 2}}, "did you mean 'export.seed'"),
    ({"export": {"samples": 3}, "effects": {"noise": {"full_wel_e": 9}}}, "did you mean 'effects.noise.full_well_e'"),
])
def test_export_config_refusals_name_the_key_and_the_type(doc, message):
    with pytest.raises(ExportConfigError, match=message):
        config_from_dict(doc)


def test_capture_and_scene_descriptions_are_strict(tmp_path):
    from synth.errors import SynthError
    from synth.scenes.scene import scene_from_dict
    from unwrap.capture import read_toml
    from unwrap.errors import UnwrapError

    toml = tmp_path / "capture.toml"
    toml.write_text("[pattern]\nsteps = 4\nfrequencies = [1, 8]\nshift_sing = -1\n")
    with pytest.raises(UnwrapError, match="did you mean 'pattern.shift_sign'"):
        read_toml(toml)
    toml.write_text("[pattern]\nsteps = 4\nfrequencies = [1, '8']\n")
    with pytest.raises(UnwrapError, match="expected an array of numbers"):
        read_toml(toml)
    with pytest.raises(SynthError, match="did you mean 'objects\\[0\\].radius_mm'"):
        scene_from_dict({"objects": [{"kind": "sphere", "radius": 3}], "patterns": {"sequence": [{"kind": "white"}]}})


def test_a_schema_is_what_the_dataclass_says():
    schema = schema_of(TrainConfig)
    assert set(schema) == {"data", "model", "loss", "optim", "run"} and schema["optim"]["steps"] is int
    assert check_table({"optim": {"lr": 1}}, schema, "t", ValueError) == {"optim": {"lr": 1}}


def test_a_section_given_in_part_keeps_the_config_defaults_of_the_rest(tmp_path):
    """[loss] is the loss module's LossWeights, whose own fourier default is 0; the config's is 0.1."""
    (tmp_path / "c.toml").write_text("[loss]\nmse = 2\n[data]\nsynthetic_samples = 3\n")
    cfg = resolve_config(tmp_path / "c.toml")
    assert cfg.loss.mse == 2.0 and cfg.loss.fourier == TrainConfig().loss.fourier == 0.1
