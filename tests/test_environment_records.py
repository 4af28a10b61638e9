"""Every result file records the environment it came from and a digest of each design it used
(issue 25): metrics.json of 'twin run' (on the twin and on the analytic model), the JUnit file
of 'twin check' (golden files: test_golden.py; sweep.json: test_sweep.py)."""
from __future__ import annotations

import json
import xml.etree.ElementTree as ET

import pytest

from test_golden import write_short
from test_scenarios import twin
from twin.outputs import fingerprint
from twin.registry import BuildContext, build_controller
from twin.scenarios import load_scenario


def _lqr_digest():
    """The LQR design's digest, or None while the LQR controller has no design_digest()."""
    own = getattr(build_controller("lqr", None, BuildContext(200.0)), "design_digest", None)
    return own() if callable(own) else None


@pytest.fixture(scope="module")
def short(tmp_path_factory):
    d = tmp_path_factory.mktemp("records")
    return write_short(d), d


def test_metrics_json_ends_with_the_environment_and_reruns_byte_identical(short):
    f, d = short
    for name in ("one", "two"):
        status, _, err = twin("run", f, "--controller", "it2,lqr", "--no-video", "--out", d / name)
        assert status == 0, err
    text = (d / "one" / "metrics.json").read_text(encoding="utf-8")
    assert (d / "two" / "metrics.json").read_text(encoding="utf-8") == text  # no timing in the fingerprint
    doc = json.loads(text)
    assert list(doc) == ["scenario", "source", "seed", "runs", "environment"]
    env = doc["environment"]
    assert env["designs"]["balance"] == load_scenario(f).design().digest()
    assert env["designs"].get("lqr") == _lqr_digest()
    here = fingerprint.environment()
    for key in ("project", "python", "machine", "packages", "numpy_simd", "kernels"):
        assert env[key] == here[key], key
    assert env["blas"]["kernel"] == here["blas"]["kernel"]
    # what precedes "environment" is byte for byte what a run wrote before it was recorded
    before = {k: v for k, v in doc.items() if k != "environment"}
    assert text.startswith(json.dumps(before, indent=2, ensure_ascii=False)[:-2] + ',\n  "environment": {')


def test_a_run_that_uses_no_lmi_design_records_none(short):
    f, d = short
    status, _, err = twin("run", f, "--controller", "lqr", "--no-video", "--out", d / "lqr")
    assert status == 0, err
    designs = json.loads((d / "lqr" / "metrics.json").read_text())["environment"]["designs"]
    assert "balance" not in designs and designs.get("lqr") == _lqr_digest()


def test_a_paper_experiment_on_the_analytic_model_records_the_environment_too(tmp_path):
    """What 'twin analytic 1' recorded before issue 27, through twin run: the environment last,
    the design's digest that of design.json (JSON keeps every bit of a float)."""
    analytic = ("--set", "plant.model=analytic", "--set", "plant.scale={}", "--set", "sensors.sensing=ideal",
                "--duration", "0.5", "--no-video")
    status, _, err = twin("run", "paper-exp1", "--controller", "it2,lqr", *analytic, "--out", tmp_path)
    assert status == 0, err
    doc = json.loads((tmp_path / "metrics.json").read_text())
    assert list(doc)[-1] == "environment"
    design = json.loads((tmp_path / "design.json").read_text())
    assert doc["environment"]["designs"]["balance"] == fingerprint.design_digest(gains=design["gains"], P=design["P"])
    assert doc["environment"]["designs"].get("lqr") == _lqr_digest()
    here = fingerprint.environment()
    for key in ("project", "python", "packages", "kernels"):
        assert doc["environment"][key] == here[key], key
    # the same design on the other plant: the same digest
    status, _, err = twin("run", "paper-exp1", "--controller", "it2", "--no-video", "--duration", "0.5",
                          "--out", tmp_path / "twin")
    assert status == 0, err
    again = json.loads((tmp_path / "twin" / "metrics.json").read_text())["environment"]["designs"]
    assert again == {"balance": doc["environment"]["designs"]["balance"]}


def test_the_junit_file_holds_the_environment_and_the_designs(short):
    f, d = short
    status, out, err = twin("check", f, "--controller", "it2,lqr", "--workers", "1", "--junit", d / "check.xml")
    assert status == 0, out + err
    suite = ET.parse(d / "check.xml").getroot().find("testsuite")
    assert suite[0].tag == "properties"  # before the test cases, as the JUnit schema has it
    props = {p.get("name"): p.get("value") for p in suite[0]}
    here = fingerprint.environment()
    assert props["environment.blas.kernel"] == here["blas"]["kernel"]
    assert props["environment.packages.numpy"] == here["packages"]["numpy"]
    assert props["environment.numpy_simd.dispatched"] == ",".join(here["numpy_simd"]["dispatched"])
    assert props["environment.designs.balance"] == load_scenario(f).design().digest()
    assert props.get("environment.designs.lqr") == _lqr_digest()
