"""The installed distribution must not shadow other distributions' top-level names."""
import importlib.metadata
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent


def test_distribution_provides_no_generic_top_level_names():
    provided = {name for name, dists in importlib.metadata.packages_distributions().items() if "sagp-batched" in dists}
    assert provided, "sagp-batched is not installed; run the README's set-up command"
    assert "kernels" not in provided and "runners" not in provided
    assert {"sagp_batched", "sagp_batched_kernels"} <= provided


def test_library_imports_from_outside_the_checkout_and_transformers_sees_no_kernels(tmp_path):
    # Run in a directory without our `kernels/` on sys.path, as an embedding job would.
    probe = (
        "import sagp_batched, sagp_batched_kernels, transformers.utils.import_utils as iu;"
        "print(iu.is_kernels_available())"
    )
    done = subprocess.run([sys.executable, "-c", probe], cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "False"


def test_checkout_kernels_directory_does_not_pass_for_hugging_face_kernels():
    # From the repository root `kernels/` is importable; transformers must still not treat it as
    # the Hugging Face distribution (it has no distribution metadata and no version).
    probe = "import transformers.utils.import_utils as iu; print(iu.is_kernels_available())"
    done = subprocess.run([sys.executable, "-c", probe], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip().splitlines()[-1] == "False"
