"""The guide's conventions and the command line's manners, as a new user meets them: a copied
built-in names itself after its file, a run says when it replaces an earlier one, an empty file
is said to run the defaults, output without a terminal holds no progress labels, counts agree
with their nouns, ``python -m twin`` and ``-V``, shell completion of scenarios and controller
kinds, ``docs/_build`` ignored, and the docs extra alone imports every documented module."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def twin(*args, cwd=None, env=None):
    return subprocess.run([sys.executable, "-m", "twin.cli", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, env={**os.environ, **(env or {})})


def test_a_copied_built_in_takes_its_files_name(tmp_path):
    r = twin("scenarios", "paper-exp2")
    assert r.returncode == 0
    assert not any(line.startswith("name") for line in r.stdout.splitlines())
    (tmp_path / "my-exp2.toml").write_text(r.stdout)
    from twin.scenarios import load_scenario

    sc = load_scenario(str(tmp_path / "my-exp2.toml"))
    assert sc.name == "my-exp2" and sc.data["duration"] == load_scenario("paper-exp2").data["duration"]


def test_a_run_says_it_replaces_an_earlier_one_and_an_empty_file_says_the_defaults_run(tmp_path):
    (tmp_path / "d.toml").write_text('description = ""\nduration = 0.05\n')
    first = twin("run", "d.toml", "--controller", "it2", "--no-video", cwd=tmp_path)
    assert first.returncode == 0, first.stderr
    assert first.stdout.splitlines()[0] == "d"  # an empty description: the name alone, not "d: "
    assert "earlier run" not in first.stdout
    second = twin("run", "d.toml", "--controller", "it2", "--no-video", cwd=tmp_path)
    assert second.returncode == 0 and "runs/d holds an earlier run; this one replaces it" in second.stdout
    # without a terminal (here: a pipe) no progress bar's label is left behind
    assert "  run" not in second.stderr and "  video" not in second.stderr
    (tmp_path / "empty.toml").write_text("")
    from twin.workflows.run import title as _title
    from twin.scenarios import load_scenario

    text = _title(load_scenario(str(tmp_path / "empty.toml")))
    assert "the file sets nothing, so the defaults run: a catch from θ0 = 0.48 rad for 15 s" in text
    assert "sets nothing" not in _title(load_scenario(str(tmp_path / "d.toml")))


def test_two_controllers_report_the_time_each_simulated(tmp_path):
    r = twin("run", "paper-exp1", "--controller", "it2,lqr", "--duration", "0.05", "--no-video", "--out",
             tmp_path / "o")
    assert r.returncode == 0, r.stderr
    assert "simulated 0.05 s for each of 2 runs in" in r.stdout


def test_counts_agree_with_their_nouns():
    from twin.commands.common import counted

    assert counted(1, "check") == "1 check" and counted(2, "run") == "2 runs" and counted(0, "sample") == "0 samples"


def test_python_m_twin_and_a_short_version_option():
    for args in (["-m", "twin", "-V"], ["-m", "twin", "--version"]):
        r = subprocess.run([sys.executable, *args], capture_output=True, text=True)
        assert r.returncode == 0 and r.stdout.startswith("twin, version "), (args, r.stdout, r.stderr)
    r = subprocess.run([sys.executable, "-m", "twin", "scenarios"], capture_output=True, text=True)
    assert r.returncode == 0 and "paper-exp1" in r.stdout


def test_the_shell_completes_scenario_names_and_controller_kinds():
    env = {"_TWIN_COMPLETE": "bash_complete"}
    r = subprocess.run([sys.executable, "-m", "twin"], capture_output=True, text=True,
                       env={**os.environ, **env, "COMP_WORDS": "twin run paper-e", "COMP_CWORD": "2"})
    names = {line.split(",", 1)[1] for line in r.stdout.splitlines() if line.startswith("plain,")}
    assert names == {"paper-exp1", "paper-exp2", "paper-exp3"}, r.stdout
    r = subprocess.run([sys.executable, "-m", "twin"], capture_output=True, text=True,
                       env={**os.environ, **env, "COMP_WORDS": "twin check paper-exp1 --controller it2,l",
                            "COMP_CWORD": "4"})
    assert "plain,it2,lqr" in r.stdout.splitlines(), r.stdout


def test_the_docs_build_folder_is_ignored(tmp_path):
    r = subprocess.run(["git", "check-ignore", "-q", "docs/_build/html/index.html"], cwd=ROOT)
    assert r.returncode == 0, "docs/_build/ is not in .gitignore"


def test_the_docs_extra_alone_imports_every_documented_module():
    """With only the base dependencies and the docs extra (every other extra's packages made
    unimportable, as in a fresh `pip install '.[docs]'`), each module the site's autodoc pages
    name imports: the site builds."""
    import re
    from importlib.metadata import packages_distributions

    meta = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]

    def names(reqs):
        return {re.split(r"[<>=!~\[; ]", r, maxsplit=1)[0].lower().replace("_", "-") for r in reqs}

    allowed = names(meta["dependencies"]) | names(meta["optional-dependencies"]["docs"])
    others = set().union(*(names(v) for k, v in meta["optional-dependencies"].items() if k != "docs")) - allowed
    blocked = sorted(mod for mod, dists in packages_distributions().items()
                     if {d.lower().replace("_", "-") for d in dists} & others)
    modules = sorted({m for page in (ROOT / "docs").rglob("*.md") if "_build" not in page.parts
                      for m in re.findall(r"\.\. auto(?:module|class|function):: ([\w.]+)", page.read_text())})
    assert "twin.envs" in modules
    code = f"""
import importlib, importlib.abc, sys
BLOCKED = set({blocked!r})
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split('.')[0] in BLOCKED:
            raise ModuleNotFoundError(f"No module named {{name!r}} (not in the docs extra)")
sys.meta_path.insert(0, Block())
bad = []
for m in {modules!r}:
    try:  # as autodoc does: the module, or the object named in it, and each name its __all__ lists
        try:
            obj = importlib.import_module(m)
        except ImportError:
            mod, _, attr = m.rpartition('.')
            obj = getattr(importlib.import_module(mod), attr)
        for name in getattr(obj, '__all__', ()):
            getattr(obj, name)
    except ImportError as exc:
        bad.append(f"{{m}}: {{exc}}")
print(bad)
"""
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == "[]", r.stdout


def test_the_scenario_reference_lists_every_key_a_map_takes():
    from twin.params import PARAMETER_DOCS
    from twin.scenarios.schema import describe

    row = next(r for r in describe() if r[0] == "plant.scale")
    assert all(f" {n}," in row[1] + "," for n in PARAMETER_DOCS), row[1]  # n_xb and g among them


def test_calibrate_list_offers_only_what_a_log_can_fit():
    r = twin("calibrate", "--list")
    assert r.returncode == 0
    offered = [line.split()[0] for line in r.stdout.splitlines() if not line.strip().startswith("(")]
    assert "dead_band" not in offered and "m_b" in offered
    assert "(dead_band: not fitted" in r.stdout


def test_a_plugin_beside_its_scenario_may_import_a_module_in_the_current_directory(tmp_path):
    """The plugins how-to as written: my_plugins.py in the folder a user works in, a lab's
    controller beside its scenario in lab/ importing it; `twin check` (a worker process) and a
    run find both, with nothing on PYTHONPATH."""
    (tmp_path / "helper_gains.py").write_text("GAINS = (-1.0, -0.08, -0.05, -0.03)\n")
    (tmp_path / "lab").mkdir()
    (tmp_path / "lab" / "lab_ctrl_x.py").write_text(
        "from helper_gains import GAINS\n\n\nclass Ctrl:\n    def reset(self, targets):\n        pass\n\n"
        "    def __call__(self, estimate, targets):\n        th, thd, ps, psd = estimate[:4]\n"
        "        u = -(GAINS[0] * th + GAINS[1] * thd + GAINS[2] * ps + GAINS[3] * psd)\n"
        "        return (0.5 * u, 0.5 * u)\n")
    (tmp_path / "lab" / "s.toml").write_text('base = "paper-exp1"\nduration = 0.2\n[initial]\ntheta = 0.05\n'
                                            '[controller]\nkinds = ["lab_ctrl_x:Ctrl"]\n[expect]\nfell = false\n')
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    # the console script, as a user runs it (python -m would put the current directory on sys.path itself)
    r = subprocess.run([str(Path(sys.executable).parent / "twin"), "check", "lab/s.toml"], cwd=tmp_path,
                       capture_output=True, text=True, env=env)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "1 check (1 run)" in r.stdout


def test_the_changelog_has_a_release_of_the_packages_version():
    import re

    version = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]["version"]
    text = (ROOT / "CHANGELOG.md").read_text(encoding="utf-8")
    releases = re.findall(r"^## (\d+\.\d+\.\d+) \((\d{4}-\d{2}-\d{2})\)$", text, re.M)
    assert releases and releases[0][0] == version, (releases[:3], version)
    conf = (ROOT / "docs" / "conf.py").read_text(encoding="utf-8")
    assert f'release = version = "{version}"' in conf


def test_each_environment_has_a_page_in_gymnasiums_layout():
    """docs/reference/envs/NAME.md per registered id: its header's spaces are the environment's
    own, and its specification (the module's docstring, rendered there) has Gymnasium's sections."""
    import importlib
    import re

    import pytest

    gymnasium = pytest.importorskip("gymnasium")
    import twin.envs  # noqa: F401

    for env_id, module in (("mtwip/Balance-v0", "twin.envs.balance"), ("mtwip/Track-v0", "twin.envs.track")):
        page = ROOT / "docs" / "reference" / "envs" / f"{env_id.split('/')[1].lower()}.md"
        text = page.read_text(encoding="utf-8")
        env = gymnasium.make(env_id)
        assert f"`{env.action_space}`" in text, (page.name, str(env.action_space))
        shape = re.search(r"Observation Space \| `Box` of shape `(\([0-9, ]+\))`", text).group(1)
        assert shape == str(env.observation_space.shape), (page.name, shape, env.observation_space.shape)
        env.close()
        assert f".. automodule:: {module}" in text and (page.parent / "_media" / f"{page.stem}.gif").is_file()
        doc = importlib.import_module(module).__doc__
        heads = [line for line in doc.splitlines() if line and not line.startswith(" ")]
        order = ["Action Space", "Observation Space", "Rewards", "Starting State", "Episode End", "Arguments",
                 "Version History"]
        found = [next(i for i, h in enumerate(heads) if h.startswith(o)) for o in order]
        assert found == sorted(found), (module, heads)


def test_the_video_names_a_run_as_the_figure_does():
    from types import SimpleNamespace

    from twin.render.video import _default_label

    exp = SimpleNamespace(name="paper-exp1")
    assert _default_label(SimpleNamespace(controller="t1", experiment=exp), 0) == "type-1  paper-exp1"
    assert _default_label(SimpleNamespace(controller="it2", experiment=None), 0) == "IT2"
    assert _default_label(SimpleNamespace(controller="my_plugins:StateFeedback", experiment=None), 0) == "StateFeedback"


def test_the_follow_camera_sees_a_catch_from_the_side_then_turns_to_the_runs_bearing():
    """paper-exp3 (a heading target of 1.5 rad): the follow camera's bearing halfway to it saw the
    catch from 0.48 rad nearly end-on (68° round from the side); with the catch's end it starts
    at the starting heading's side view and turns to the halfway bearing after the catch."""
    import math

    import pytest

    from twin.render.scene import SWING_S, Camera, camera_mode

    cam = camera_mode("follow", 0.0, None, 1.5, catch_end=1.5)
    assert cam.yaw_at(0.0) == 25.0 and cam.yaw_at(1.5) == 25.0
    assert cam.yaw_at(1.5 + SWING_S) == pytest.approx(25.0 + math.degrees(0.75))
    mid = cam.yaw_at(1.5 + 0.5 * SWING_S)
    assert 25.0 < mid < 25.0 + math.degrees(0.75)
    assert camera_mode("follow", 0.0, None, 1.5).yaw == pytest.approx(25.0 + math.degrees(0.75))  # no catch: as before
    assert camera_mode("follow", 0.0, None, None, catch_end=1.5).swing is None  # no turn to show
    with pytest.raises(Exception, match="swing"):
        Camera(swing=(2.0, 1.0, 30.0))


def test_a_paper_exp3_video_shows_the_catch_side_on(tmp_path):
    """The frames of the catch are taken with the starting heading's side view (the runner hands
    the figure's catch window to the camera)."""
    from twin.scenarios import load_scenario
    from twin.outputs.run_directory import catch_end as _catch_end

    from twin.sim.runs import Run  # noqa: F401 - the runner's runs
    from twin.workflows.run import run_scenario

    r = run_scenario(load_scenario("paper-exp3", ["duration=6"]), ("it2",), out=None, video=False)
    end = _catch_end(r.runs)
    assert end is not None and 1.0 <= end <= 2.0, end
    r1 = run_scenario(load_scenario("paper-exp1", ["duration=6", "initial.theta=0.0"]), ("it2",), out=None,
                      video=False)
    assert _catch_end(r1.runs) is None


def test_a_catch_plays_slowly_with_a_caption_then_in_real_time(tmp_path):
    import numpy as np
    import pytest

    from twin.render.video import frame_times, render_video
    from twin.scenarios import load_scenario
    from twin.outputs.run_directory import SLOW_CATCH
    from twin.workflows.run import run_scenario

    t = frame_times(3.0, 30, (1.5, SLOW_CATCH))
    assert len(t) == 180 + 46 and np.allclose(np.diff(t[:180]), 1 / 120) and np.allclose(np.diff(t[180:]), 1 / 30)
    assert t[-1] == 3.0 and np.array_equal(frame_times(3.0, 30), np.arange(91) / 30)
    runs = run_scenario(load_scenario("paper-exp1", ["duration=0.2"]), ("it2",), out=None, video=False).runs
    for bad in ((1.0, 40.0), (0.0, 4.0), "slow"):
        with pytest.raises(Exception, match="slow must be"):
            render_video(runs, tmp_path / "x.mp4", slow=bad)
    info = render_video(runs, tmp_path / "v.mp4", fps=10, size=(160, 120), slow=(0.1, 4.0), renderer="tiny",
                        parallel=False)
    assert info.frames == 4 + 2  # 0, 0.025, 0.05, 0.075 s at a quarter speed; then 0.1, 0.2 s
    from test_render import read_video

    frames = read_video(tmp_path / "v.mp4")
    assert len(frames) == 6
    def band(f) -> int:
        """Dark grey pixels (the caption's darkened box) in the caption's band, bottom centre,
        right of the markers' key (which this small frame puts under the text box); the path
        drawn on the floor is orange: not counted."""
        b = f[100:118, 105:135].astype(int)
        return int(((b.max(axis=2) < 140) & (b.max(axis=2) - b.min(axis=2) < 40)).sum())

    assert band(frames[0]) > band(frames[5]) + 150, (band(frames[0]), band(frames[5]))  # while slow, not after
