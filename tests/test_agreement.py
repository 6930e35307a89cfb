"""Label agreement against hand-computed figures: Cohen's kappa, the Wilson interval, the confusion matrix, the
disagreements by phase and by region, and the regions themselves."""
import numpy as np
import pytest

from sagp_batched.datasets.agreement import agreement_markdown, cohen_kappa, grasp_regions, label_agreement


def _raters(both_held, only_reference, only_ours, both_dropped):
    reference = np.array([1] * both_held + [1] * only_reference + [0] * only_ours + [0] * both_dropped, dtype=bool)
    ours = np.array([1] * both_held + [0] * only_reference + [1] * only_ours + [0] * both_dropped, dtype=bool)
    return reference, ours


@pytest.mark.parametrize("cells, kappa", [
    # po = 35/50 = 0.7; reference held 25/50, ours 30/50: pe = 0.5 * 0.6 + 0.5 * 0.4 = 0.5; (0.7 - 0.5) / 0.5.
    ((20, 5, 10, 15), 0.4),
    # po = 0.8; both held 4/10: pe = 0.16 + 0.36 = 0.52; 0.28 / 0.48.
    ((3, 1, 1, 5), 0.28 / 0.48),
    # po = 0.9; reference 1/10, ours 0/10: pe = 0.1 * 0 + 0.9 * 1 = 0.9; (0.9 - 0.9) / 0.1: chance-level.
    ((0, 1, 0, 9), 0.0),
    ((6, 0, 0, 4), 1.0),
    ((0, 5, 5, 0), -1.0),
])
def test_kappa_matches_the_hand_computed_value(cells, kappa):
    reference, ours = _raters(*cells)
    assert cohen_kappa(reference, ours) == pytest.approx(kappa)
    assert label_agreement(reference, ours, [""] * len(ours), ["middle"] * len(ours))["kappa"] == pytest.approx(kappa)


def test_kappa_is_undefined_where_both_gave_one_label_only():
    assert cohen_kappa(np.ones(5, bool), np.ones(5, bool)) is None
    assert cohen_kappa(np.zeros(0, bool), np.zeros(0, bool)) is None


def test_the_agreement_counts_confusion_shares_and_disagreements():
    reference, ours = _raters(3, 1, 1, 5)
    # Rows: 3 both held, 1 only the reference held (we dropped it on the shake), 1 only we held, 5 both dropped.
    phases = ["", "", "", "shake", "", "close", "close", "lift", "grasp_pose", "close"]
    regions = ["top", "top", "middle", "bottom", "bottom", "top", "middle", "bottom", "top", "top"]
    result = label_agreement(reference, ours, phases, regions)
    assert (result["n"], result["agree"], result["agreement"]) == (10, 8, 0.8)
    # Wilson 95 % for 8/10: 0.4902 .. 0.9433.
    assert result["agreement_ci95"] == pytest.approx([0.4902, 0.9433], abs=1e-4)
    assert result["confusion"] == {"reference_held": {"ours_held": 3, "ours_dropped": 1},
                                   "reference_dropped": {"ours_held": 1, "ours_dropped": 5}}
    assert result["positive_share"] == {"reference": 0.4, "ours": 0.4}
    assert result["disagreements_by_phase"] == {"shake": 1, "held": 1}
    assert result["disagreements_by_region"] == {
        "bottom": {"n": 3, "disagree": 2, "agreement": pytest.approx(1 / 3)},
        "middle": {"n": 2, "disagree": 0, "agreement": 1.0},
        "top": {"n": 5, "disagree": 0, "agreement": 1.0},
    }
    text = agreement_markdown(result, "Mug")
    assert text.startswith("# Mug") and "| held | 3 | 1 |" in text and "| dropped | 1 | 5 |" in text
    assert "| shake | 1 |" in text and "| bottom | 3 | 2 | 33.3 % |" in text and "Cohen's kappa: 0.583" in text


def test_the_inputs_must_be_one_per_grasp():
    with pytest.raises(ValueError, match="one of each per grasp"):
        label_agreement(np.ones(3, bool), np.ones(3, bool), ["", ""], ["top"] * 3)


def test_regions_are_thirds_along_the_longest_side_of_the_box():
    upright = np.array([[-0.02, -0.02, 0.0], [0.02, 0.02, 0.3]])
    centres = np.array([[0.0, 0.0, 0.05], [0.0, 0.0, 0.15], [0.0, 0.0, 0.25], [0.0, 0.0, -0.01], [0.0, 0.0, 0.4]])
    assert grasp_regions(centres, upright) == ["bottom", "middle", "top", "bottom", "top"], "outside the box: the nearer end"
    lying = np.array([[-0.15, -0.02, 0.0], [0.15, 0.02, 0.04]])
    assert grasp_regions(np.array([[-0.1, 0.0, 0.03], [0.0, 0.0, 0.03], [0.12, 0.0, 0.0]]), lying) == ["bottom", "middle", "top"]
    with pytest.raises(ValueError, match="upper > lower"):
        grasp_regions(centres, np.zeros((2, 3)))
