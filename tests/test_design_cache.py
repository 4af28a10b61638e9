"""The on-disk cache of LMI designs (twin.controllers.design_cache): a cached design is the
fresh one bit for bit; a bad entry is never trusted but noted and solved again; --no-cache
bypasses it; 'twin cache clear' empties it; a run served from it never imports cvxpy."""
import dataclasses
import functools
import hashlib
import json
import subprocess
import sys
import tempfile

import numpy as np
import pytest

from twin.controllers import design_cache
from twin.controllers.designs import balance_design
from twin.controllers.lmi import design_balance_gains

# the disk cache alone, as a new process finds it (not this process's designs)
cached_design = functools.partial(balance_design, cache=True, hold=False)
from twin.params import NOMINAL

DECAY = 2.5  # options of their own, so that no other test's entry is found by accident


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("TWIN_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def _entry(cache):
    files = sorted(cache.glob("lmi-*.json"))
    assert len(files) == 1, files
    return files[0]


def _same_bits(a, b, solve_time=True):
    """Every field of two designs (from_cache aside) equal, floats and arrays by their bytes;
    solve_time=False: a design solved twice, whose solve times differ."""
    for f in dataclasses.fields(a):
        if f.name == "from_cache" or (f.name == "solve_time_s" and not solve_time):
            continue
        x, y = getattr(a, f.name), getattr(b, f.name)
        if isinstance(x, np.ndarray):
            assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), f.name
        elif isinstance(x, float):
            assert isinstance(y, float) and x.hex() == y.hex(), f.name
        elif f.name == "certificate":
            assert list(x.lmi_margins) == list(y.lmi_margins)
            assert [v.hex() for v in x.lmi_margins.values()] == [v.hex() for v in y.lmi_margins.values()]
            for g in ("lyapunov_margin", "epsilon_margin", "rho_margin"):
                assert getattr(x, g).hex() == getattr(y, g).hex(), g
            assert x.passed is y.passed is True
        else:
            assert x == y, f.name


def test_cached_design_equals_the_fresh_one_bit_for_bit(cache):
    fresh = cached_design(decay_rate=DECAY)
    assert not fresh.from_cache and _entry(cache).is_file()
    cached = cached_design(decay_rate=DECAY)
    assert cached.from_cache
    _same_bits(fresh, cached)
    assert json.dumps(fresh.to_json_dict()) == json.dumps(cached.to_json_dict())
    # and it is the design a cache-less call solves (the solver is deterministic)
    again = design_balance_gains(decay_rate=DECAY)
    assert again.gains.tobytes() == cached.gains.tobytes() and again.P.tobytes() == cached.P.tobytes()


def test_the_key_covers_parameters_options_and_the_design_code_and_nothing_else(cache, monkeypatch):
    base = design_cache.inputs_of(NOMINAL, 0.5, 2.0, 3.0, None, None)
    keys = {design_cache.key_of(base)}
    for changed in (design_cache.inputs_of(NOMINAL.replace(m_b=2.58 * (1 + 1e-15)), 0.5, 2.0, 3.0, None, None),
                    design_cache.inputs_of(NOMINAL, 0.5, 2.0, 3.0, None, "SCS"),
                    design_cache.inputs_of(NOMINAL, 0.5, 2.0, 3.0, 10.0, None)):
        keys.add(design_cache.key_of(changed))
    monkeypatch.setitem(design_cache._versions(), "design_code_sha256", "0" * 64)
    keys.add(design_cache.key_of(design_cache.inputs_of(NOMINAL, 0.5, 2.0, 3.0, None, None)))
    assert len(keys) == 5
    # the design is the program's unique point (lmi_center): the solvers' and numpy's versions,
    # Python's and the machine do not change its numbers, so they are not in the key
    assert set(base["versions"]) == {"design_code_sha256"}


def _rewrite(path, edit):
    doc = json.loads(path.read_text())
    edit(doc)
    path.write_text(json.dumps(doc))


def _reseal(doc):  # a checksum that matches the edited body: only the design's own check can catch it
    doc["checksum"] = hashlib.sha256(design_cache._canonical(doc["design"])).hexdigest()


def _flip_gains(doc):
    doc["design"]["gains"]["hex"] = [float.hex(-float.fromhex(v)) for v in doc["design"]["gains"]["hex"]]
    _reseal(doc)


@pytest.mark.parametrize("damage, why", [
    (lambda p: p.write_bytes(b"\x00\xff garbage \x13"), "not valid JSON"),
    (lambda p: p.write_bytes(p.read_bytes()[:len(p.read_bytes()) // 2]), "not valid JSON"),
    (lambda p: p.write_text(""), "not valid JSON"),
    (lambda p: _rewrite(p, lambda d: d.update(key="0" * 64)), "made for other inputs"),
    (lambda p: _rewrite(p, lambda d: d["inputs"]["options"].update(rho=(3.0).hex())), "made for other inputs"),
    (lambda p: _rewrite(p, lambda d: d["design"]["P"]["hex"].__setitem__(0, (1.5).hex())), "checksum mismatch"),
    (lambda p: _rewrite(p, lambda d: (d["design"]["P"]["hex"].__setitem__(0, "nan"), _reseal(d))), "not finite"),
    (lambda p: _rewrite(p, lambda d: (d["design"]["Q"].update(shape=[2, 8]), _reseal(d))), "has shape"),
    (lambda p: _rewrite(p, lambda d: (d["design"].pop("solver"), _reseal(d))), "missing or of the wrong type"),
    (lambda p: _rewrite(p, _flip_gains), "do not make V"),
    (lambda p: (p.unlink(), p.mkdir()), "unreadable"),
])
def test_a_bad_entry_is_noted_and_solved_again(cache, capsys, damage, why):
    fresh = cached_design(decay_rate=DECAY)
    path = _entry(cache)
    damage(path)
    capsys.readouterr()
    d = cached_design(decay_rate=DECAY)
    err = capsys.readouterr().err
    assert not d.from_cache, "a damaged entry was trusted"
    _same_bits(fresh, d, solve_time=False)
    lines = err.strip().splitlines()
    assert lines[0].startswith("note: design cache: ignored") and why in lines[0], err
    # one line; only an entry that cannot be replaced (a directory in its place) adds one more
    assert len(lines) == 1 or (why == "unreadable" and len(lines) == 2 and "could not write" in lines[1]), err
    if path.is_file():  # the recomputed design replaced the bad file, and is served next time
        assert cached_design(decay_rate=DECAY).from_cache


def test_an_unwritable_cache_is_a_note_not_an_error(tmp_path, monkeypatch, capsys):
    (tmp_path / "file").write_text("")
    monkeypatch.setenv("TWIN_CACHE_DIR", str(tmp_path / "file" / "cache"))  # below a file: cannot exist
    d = cached_design(decay_rate=DECAY)
    assert d.certificate.passed and "could not write" in capsys.readouterr().err


def test_cache_directory_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv("TWIN_CACHE_DIR", str(tmp_path / "a"))
    assert design_cache.cache_dir() == tmp_path / "a"
    monkeypatch.delenv("TWIN_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "x"))
    assert design_cache.cache_dir() == tmp_path / "x" / "mtwip-twin"
    monkeypatch.setenv("XDG_CACHE_HOME", "relative/ignored")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert design_cache.cache_dir() == tmp_path / "home" / ".cache" / "mtwip-twin"


def _twin(cache, *args):
    env = {**__import__("os").environ, "TWIN_CACHE_DIR": str(cache)}
    return subprocess.run([sys.executable, "-m", "twin.cli", *args], capture_output=True, text=True,
                          cwd=tempfile.gettempdir(), env=env)


def test_no_cache_bypasses_and_clear_empties(tmp_path):
    cache = tmp_path / "cache"
    r = _twin(cache, "design", "--decay-rate", str(DECAY), "--no-cache")
    assert r.returncode == 0, r.stderr
    assert not list(cache.glob("lmi-*.json")) and "from the design cache" not in r.stdout  # not written
    r = _twin(cache, "design", "--decay-rate", str(DECAY))
    assert r.returncode == 0 and "from the design cache" not in r.stdout
    entry = _entry(cache)
    r = _twin(cache, "design", "--decay-rate", str(DECAY))
    assert r.returncode == 0 and "from the design cache" in r.stdout
    entry.write_bytes(b"garbage")  # --no-cache does not even read it: no note
    r = _twin(cache, "design", "--decay-rate", str(DECAY), "--no-cache")
    assert r.returncode == 0 and "design cache" not in r.stdout + r.stderr and entry.read_bytes() == b"garbage"
    (cache / "keep-me.txt").write_text("not ours")
    r = _twin(cache, "cache", "info")
    assert r.returncode == 0 and f"{cache}: 1 cached design" in r.stdout
    r = _twin(cache, "cache", "clear")
    assert r.returncode == 0 and "removed 1 file" in r.stdout, r.stdout + r.stderr
    assert not list(cache.glob("lmi-*")) and (cache / "keep-me.txt").read_text() == "not ours"
    assert "0 cached designs" in _twin(cache, "cache", "info").stdout


RUN = """
import sys
from twin.cli import main
sys.argv = ["twin", "run", "paper-exp3", "--duration", "1", "--no-video", "--controller", "it2", "--out", {out!r}]
try:
    main()
except SystemExit as exc:
    assert exc.code == 0, exc.code
print("SOLVER", any(m in sys.modules for m in ("cvxpy", "clarabel", "scs")))
"""


def test_a_cached_run_does_not_import_cvxpy(tmp_path):
    env = {**__import__("os").environ, "TWIN_CACHE_DIR": str(tmp_path / "cache")}

    def run():
        r = subprocess.run([sys.executable, "-c", RUN.format(out=str(tmp_path / "out"))], capture_output=True,
                           text=True, env=env, cwd=tempfile.gettempdir())
        assert r.returncode == 0, r.stderr
        return r.stdout.strip().splitlines()[-1]

    assert run() == "SOLVER True"  # cold: solved (the default design goes to Clarabel directly), and stored
    assert run() == "SOLVER False"  # warm: served from the cache, no solver imported
