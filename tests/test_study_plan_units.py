"""What a study is made of: its units, and the tasks an object set can serve."""
import pytest

from sagp_batched.config import ConfigError, load_config
from sagp_batched.study.study_run import plan_units
from sagp_batched.world.objects import ObjectSet, load_object_set

OBJECTS = load_object_set(None)


def _config(tasks):
    return load_config("ci", overrides={"run": {"objects": ["025_mug"], "tasks": tasks, "n_trials": 2}})


def test_t3_on_an_object_set_without_distractors_is_refused_instead_of_repeating_t1():
    without_distractors = ObjectSet("targets only", OBJECTS.targets())
    with pytest.raises(ConfigError, match="task t3 needs distractors and the object set targets only has none"):
        plan_units(_config(["t1", "t3"]), without_distractors, ["go"])
    assert len(plan_units(_config(["t1", "t2"]), without_distractors, ["go"])) == 4


def test_units_cover_every_object_task_and_trial_once():
    units = plan_units(_config(["t1", "t3"]), OBJECTS, ["go", "sagp"])
    assert [(u.object_id, u.task, u.trial, u.methods) for u in units] == [
        ("025_mug", task, trial, ("go", "sagp")) for task in ("t1", "t3") for trial in range(2)
    ]
