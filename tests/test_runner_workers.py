"""The study and dataset runners say in their first lines how many workers they use and what chose that count."""
import pytest

import runners.batch
import runners.datagen
from runners.cli import config_from_flags, workers_line
from sagp_batched.config.run import available_cores


@pytest.mark.parametrize("runner", [runners.batch, runners.datagen], ids=["batch", "datagen"])
@pytest.mark.parametrize("argv, expected", [
    ([], f"workers: {available_cores()} (the cores available; --workers N to change)"),
    (["--workers", "3"], "workers: 3 (--workers)"),
    (["--profile", "ci", "--workers", "1"], "workers: 1 (--workers)"),
])
def test_the_workers_line_names_what_chose_the_count(runner, argv, expected):
    args = runner.build_parser().parse_args(argv)
    assert workers_line(args, config_from_flags(args, runner.SETTING_FLAGS)) == expected


def test_a_profiles_worker_count_is_kept_and_named(tmp_path):
    profile = tmp_path / "two.toml"
    profile.write_text("[run]\nworkers = 2\n")
    args = runners.batch.build_parser().parse_args(["--profile", str(profile)])
    assert workers_line(args, config_from_flags(args, runners.batch.SETTING_FLAGS)) == (
        f"workers: 2 ([run] workers of profile {profile}; --workers N to change)")
