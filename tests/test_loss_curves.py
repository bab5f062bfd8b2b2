"""Loss curves from metrics.csv: the loss terms, training per step and validation per epoch, nothing else."""

import pytest

from lead_s2r.report.loss_curves import plot_loss_curves, read_curves

#: Lightning's CSV logger layout: a row per logged step, a column per metric, blank where it was not logged.
METRICS = """epoch,step,train/batch_size/navsim,train/loss,train/navsim/waypoints,val/navsim/ade,val/navsim/waypoints
0,0,,9.5,9.0,,
0,1,,7.0,6.5,,
0,1,4.0,,,,
0,1,,,,3.2,4.25
1,2,,5.0,4.5,,
1,3,,3.0,2.5,,
1,3,,,,1.1,2.0
"""


def test_curves_keep_loss_terms_by_step_and_drop_batch_sizes_and_displacements(tmp_path):
    path = tmp_path / "metrics.csv"
    path.write_text(METRICS)
    assert read_curves(path) == {
        "train/loss": [(0, 9.5), (1, 7.0), (2, 5.0), (3, 3.0)],
        "train/navsim/waypoints": [(0, 9.0), (1, 6.5), (2, 4.5), (3, 2.5)],
        "val/navsim/waypoints": [(1, 4.25), (3, 2.0)],
    }
    png = plot_loss_curves(path, tmp_path / "run" / "loss_curves.png", "toy")
    assert png.read_bytes().startswith(b"\x89PNG")


def test_a_log_without_loss_terms_is_an_error_naming_the_file(tmp_path):
    path = tmp_path / "metrics.csv"
    path.write_text("epoch,step,val/navsim/ade\n0,0,1.0\n")
    with pytest.raises(ValueError, match=r"metrics\.csv: no train/ or val/ loss terms"):
        plot_loss_curves(path, tmp_path / "out.png")
