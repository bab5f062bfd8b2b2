"""Loss curves from metrics.csv: the loss terms, training per step and validation per epoch, nothing else."""

import pytest

from lead_s2r.errors import UserError
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
    with pytest.raises(UserError, match=r"metrics\.csv: no train/ or val/ loss terms"):
        plot_loss_curves(path, tmp_path / "out.png")


@pytest.mark.parametrize(
    ("log", "message"),
    [
        (b"epoch,step,train/loss\n0,1,2.5\x00\n", "could not convert string to float"),  # was a ValueError traceback
        (b"epoch,step,train/loss\n0,x,2.5\n", "could not convert string to float: 'x'"),  # was int('x')
        (b"epoch,step,train/loss\n0,1,2.5,7\n", "line 2 has more cells than the header"),  # was read as 2.5
        (b"epoch,step,train/loss\n0,1,\xff\n", "'utf-8' codec"),  # was a UnicodeDecodeError traceback
        (b"epoch,spep,train/loss\n0,1,2.5\n", "no step column"),  # was a KeyError traceback
        (None, "No such file"),  # was a FileNotFoundError traceback
    ],
)
def test_a_damaged_log_is_named_by_the_one_reader(tmp_path, log, message):
    """The quickstart's loss curves read metrics.csv as the report does (report.training_log.TrainingLog)."""
    path = tmp_path / "metrics.csv"
    if log is not None:
        path.write_bytes(log)
    with pytest.raises(UserError, match=rf"metrics\.csv: not a Lightning CSV log \(.*{message}"):
        plot_loss_curves(path, tmp_path / "out.png")
    assert not (tmp_path / "out.png").exists()
