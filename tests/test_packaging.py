"""The installed distribution is the product: it ships every profile and data file, runs from any directory,
and does not shadow other distributions' top-level names."""
import ast
import importlib.metadata
import json
import os
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from sagp_batched.config import ConfigError, load_config, named_profiles, resolve_profile_path

REPO = Path(__file__).resolve().parent.parent
# Checkout folder -> installed package folder, as pyproject.toml's package-dir maps them.
INSTALLED_AS = {
    "sagp_batched": "sagp_batched",
    "kernels": "sagp_batched_kernels",
    "runners": "sagp_batched_runners",
    "profiles": "sagp_batched/profiles",
}
EMBEDDED_YCB = "sagp_batched/data/ycb"
PROFILE_NAMES = sorted(path.stem for path in (REPO / "profiles").glob("*.toml"))


def _files_to_ship(folder: Path):
    return (path for path in sorted(folder.rglob("*")) if path.is_file() and "__pycache__" not in path.parts)


@pytest.fixture(scope="module")
def built_wheel(tmp_path_factory) -> Path:
    """A wheel built the way `pip wheel .` builds one, from a copy of the sources (no build/ left in the checkout)."""
    work = tmp_path_factory.mktemp("wheel")
    source = work / "source"
    source.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(REPO / name, source / name)
    for folder in INSTALLED_AS:
        shutil.copytree(REPO / folder, source / folder, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    done = subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(work / "dist"), str(source)],
        capture_output=True, text=True, timeout=600,
    )
    assert done.returncode == 0, done.stdout + done.stderr
    (wheel,) = (work / "dist").glob("sagp_batched-*.whl")
    return wheel


def test_distribution_provides_no_generic_top_level_names():
    provided = {name for name, dists in importlib.metadata.packages_distributions().items() if "sagp-batched" in dists}
    assert provided, "sagp-batched is not installed; run the README's set-up command"
    assert "kernels" not in provided and "runners" not in provided
    assert {"sagp_batched", "sagp_batched_kernels"} <= provided


# Whether Hugging Face's `kernels` distribution is installed here: transformers requires it from 5.25 on.
HF_KERNELS_INSTALLED = any(name == "kernels" for name in importlib.metadata.packages_distributions().get("kernels", ()))
# What `import kernels` gives, printed by a probe: Hugging Face's module file, or "none".
KERNELS_PROBE = (
    "import os\n"
    "try:\n    import kernels\n    print(os.path.realpath(kernels.__file__))\n"
    "except ModuleNotFoundError:\n    print('none')\n"
)


def _probe_kernels(cwd: Path, prelude: str = "") -> list[str]:
    probe = prelude + KERNELS_PROBE + (
        "import transformers.utils.import_utils as iu\nprint(iu.is_kernels_available())\n"
        # The import that fails where the checkout's kernels/ shadows Hugging Face's.
        "import transformers.integrations.hub_kernels\n"
    )
    done = subprocess.run([sys.executable, "-c", probe], cwd=cwd, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    return done.stdout.strip().splitlines()[-2:]


def _hugging_faces_or_none(lines: list[str]) -> None:
    found, available = lines
    if HF_KERNELS_INSTALLED:
        assert found != "none" and not Path(found).is_relative_to(REPO), f"`import kernels` gave {found}, not Hugging Face's"
        assert available in ("True", "False")  # transformers judges the version range itself
    else:
        assert (found, available) == ("none", "False")


def test_library_imports_from_outside_the_checkout_and_the_name_kernels_is_hugging_faces_or_none(tmp_path):
    # Run in a directory without our `kernels/` on sys.path, as an embedding job would.
    _hugging_faces_or_none(_probe_kernels(tmp_path, "import sagp_batched, sagp_batched_kernels\n"))


def test_from_the_checkout_the_name_kernels_is_hugging_faces_or_none():
    # From the repository root `kernels/` is importable by that name; it hands the name over.
    _hugging_faces_or_none(_probe_kernels(REPO))


def test_from_the_checkout_without_hugging_faces_distribution_kernels_is_no_module():
    hidden = (
        "import importlib.metadata as m\n_real = m.distribution\n"
        "def _hide(name):\n    if name == 'kernels':\n        raise m.PackageNotFoundError(name)\n    return _real(name)\n"
        "m.distribution = _hide\n"
    )
    done = subprocess.run([sys.executable, "-c", hidden + KERNELS_PROBE], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "none"


def test_every_profile_file_is_a_named_profile_that_load_config_reads_as_package_data():
    assert PROFILE_NAMES, "no profiles/*.toml in the checkout"
    assert sorted(named_profiles()) == PROFILE_NAMES
    for name in PROFILE_NAMES:
        resource = resolve_profile_path(name)
        assert resource.read_text() == (REPO / "profiles" / f"{name}.toml").read_text()
        load_config(name)


def test_profile_given_as_a_path_is_read_from_that_file(tmp_path):
    own = tmp_path / "own.toml"
    own.write_text("[run]\nn_trials = 7\n")
    assert load_config(own).run.n_trials == 7
    assert load_config(str(own)).run.n_trials == 7
    with pytest.raises(ConfigError, match=f"no TOML file at {tmp_path / 'missing.toml'} .*named profiles: ci"):
        load_config(tmp_path / "missing.toml")


def test_wheel_holds_every_module_profile_and_data_file_and_nothing_else(built_wheel):
    expected = {
        f"{installed}/{path.relative_to(REPO / folder).as_posix()}"
        for folder, installed in INSTALLED_AS.items()
        for path in _files_to_ship(REPO / folder)
    }
    with zipfile.ZipFile(built_wheel) as wheel:
        shipped = {name for name in wheel.namelist() if ".dist-info/" not in name}
        top_level = wheel.read(next(n for n in wheel.namelist() if n.endswith(".dist-info/top_level.txt"))).decode()
        ycb_index = json.loads(wheel.read(f"{EMBEDDED_YCB}/objects.json"))
        urdfs = {name: wheel.read(name).decode() for name in shipped if name.endswith(".urdf")}
    assert shipped == expected, f"missing: {sorted(expected - shipped)}; unexpected: {sorted(shipped - expected)}"
    assert {f"sagp_batched/profiles/{name}.toml" for name in PROFILE_NAMES} <= shipped
    assert sorted(top_level.split()) == ["sagp_batched", "sagp_batched_kernels", "sagp_batched_runners"]
    # The embedded YCB set is whole: every file its index and its URDFs name is in the wheel.
    objects = {object_id: entry for object_id, entry in ycb_index.items() if "urdf" in entry}
    assert "025_mug" in objects and any(entry["texture"] for entry in objects.values())
    for entry in objects.values():
        named = [entry["urdf"], entry["visual_mesh"], entry["collision_mesh"], entry["texture"]]
        assert {f"{EMBEDDED_YCB}/{name}" for name in named if name} <= shipped, entry["urdf"]
    for urdf, text in urdfs.items():
        meshes = set(re.findall(r'filename="([^"]+)"', text))
        assert meshes and {f"{urdf.rsplit('/', 1)[0]}/{mesh}" for mesh in meshes} <= shipped, urdf


def _readme_api_example() -> str:
    readme = (REPO / "README.md").read_text()
    section = readme[readme.index("## Python API"):]
    start = section.index("```python\n") + len("```python\n")
    return section[start:section.index("```", start)]


@pytest.mark.slow
def test_installed_wheel_runs_the_console_scripts_and_the_readme_example_outside_the_checkout(built_wheel, tmp_path):
    # --system-site-packages brings torch and the other dependencies; that site also holds an editable
    # install of some checkout, so every check below asserts the wheel's own copy is the one in use.
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)], check=True, timeout=300)
    python, bin_dir = venv / "bin" / "python", venv / "bin"
    done = subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-deps", str(built_wheel)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    env = {key: value for key, value in os.environ.items() if key not in ("SAGP_YCB_DIR", "PYTHONPATH")}

    def run(*command: str):
        return subprocess.run(list(command), cwd=elsewhere, env=env, capture_output=True, text=True, timeout=600)

    probe = (
        "import json, sagp_batched, sagp_batched_kernels, sagp_batched_runners\n"
        "from sagp_batched import load_config\n"
        "from sagp_batched.config import resolve_profile_path\n"
        "from sagp_batched.world.objects import load_object_set\n"
        "assert load_config('datagen').run.export_grasps\n"
        "print(json.dumps({'modules': [m.__file__ for m in (sagp_batched, sagp_batched_kernels, sagp_batched_runners)],"
        " 'datagen': str(resolve_profile_path('datagen')), 'objects': load_object_set(None).source}))\n"
    )
    done = run(str(python), "-c", probe)
    assert done.returncode == 0, done.stderr
    found = json.loads(done.stdout.strip().splitlines()[-1])
    site = venv.resolve()
    for path in (*found["modules"], found["datagen"], found["objects"].split(":", 1)[1]):
        assert Path(path).resolve().is_relative_to(site), f"{path} is not the wheel's copy in {site}"

    out = tmp_path / "run"
    done = run(str(bin_dir / "sagp-batch"), "--n-trials", "1", "--objects", "025_mug", "--tasks", "t1",
               "--methods", "go", "--out", str(out))
    assert done.returncode == 0, done.stderr
    assert f"objects: embedded compact YCB:{site}" in done.stderr
    records = [json.loads(line) for line in (out / "trials.jsonl").read_text().splitlines()]
    assert [(r["object"], r["task"], r["method"]) for r in records] == [("025_mug", "t1", "go")]

    done = run(str(bin_dir / "sagp-batch"), "--profile", "no_such_profile", "--n-trials", "1")
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1] == (
        f"error: profile 'no_such_profile' not found: no such named profile (named profiles: {', '.join(PROFILE_NAMES)})"
    )

    example = elsewhere / "api_example.py"
    example.write_text(_readme_api_example())
    done = run(str(python), str(example))
    assert done.returncode == 0, done.stderr
    best = ast.literal_eval(done.stdout.strip().splitlines()[-1])  # the example prints best.record(), a plain dict
    assert {"position", "quat_xyzw", "width", "score"} <= set(best) and len(best["position"]) == 3
