"""``torch.save`` files (LEAD's ``model*.pth``, Lightning's ``.ckpt``) read with their damage named, not loaded.

torch reads its zip archive without checking the CRC32 of each member, so a flipped bit inside a tensor loads as
another weight and a model silently predicts something else. :func:`check_archive` checks every CRC first (about
0.3 s per 250 MB); :func:`load` then reads the file weights-only. Either failing is a :class:`UserError` naming the
file, whatever the damage made zipfile or torch raise. So is a checkpoint of the TransFuser network that LEAD's own
(``lead_s2r.models.lead_driver.LeadDriver``) replaced: every reader of a checkpoint (``--ckpt_path``, ``init_from``,
the CARLA agent, ``export-lead``) comes through :func:`load`, so each says the same one line instead of failing on the
class's import or on thousands of missing keys.
"""

import pickle
import zipfile
import zlib
from pathlib import Path
from typing import Any

import torch

from lead_s2r.errors import UserError

#: What zipfile raises on a damaged archive: a bad directory (BadZipFile), a member name that is not UTF-8
#: (UnicodeDecodeError), an offset before the file's start (OSError) or data past its end (EOFError), the flag of
#: an encrypted member (RuntimeError), a member marked compressed (zlib.error) or by an unknown method
#: (NotImplementedError).
ZIP_DAMAGE = (zipfile.BadZipFile, UnicodeDecodeError, OSError, EOFError, RuntimeError, zlib.error, NotImplementedError)
#: What torch.load raises on a file that is no zip archive or whose CRCs hold but which is no checkpoint: no zip
#: directory in a small file (RuntimeError) or a seek before the start of a larger cut one (OSError), a bad pickle
#: (UnpicklingError), no bytes (EOFError), a record that is no number or text (ValueError).
TORCH_DAMAGE = (RuntimeError, OSError, pickle.UnpicklingError, EOFError, ValueError)
#: The removed network's class path, as a checkpoint's ``hyper_parameters`` name it, and the state-dict prefixes only
#: it had (under the LightningModule's ``model.``), for checkpoints written before hyper_parameters described it.
REMOVED_NETWORK = "lead_s2r.models.tfv6.TFv6"
REMOVED_NETWORK_KEYS = ("model.backbone.", "model.planner.", "model.bev_tokens.")


def check_archive(file: Path, zip_only: bool = False) -> None:
    """Every member of ``file`` passes its CRC check. A file that is no zip archive (torch's legacy format, or one cut
    before its directory) is refused with ``zip_only`` (what torch.save has written since torch 1.6, and every
    Lightning checkpoint), else left to :func:`load` to judge."""
    if zip_only and file.is_file() and not zipfile.is_zipfile(file):
        raise UserError(f"{file}: not a torch checkpoint archive (cut short or another kind of file); copy it again")
    try:
        if zipfile.is_zipfile(file):
            with zipfile.ZipFile(file) as archive:
                damaged = archive.testzip()
            if damaged is not None:
                raise UserError(f"{file}: its member {damaged} fails its CRC check; the file is damaged, copy it again")
    except ZIP_DAMAGE as err:
        raise UserError(f"{file}: a damaged zip archive ({err!r}); copy the checkpoint again") from None


def load(file: Path, zip_only: bool = False) -> Any:
    """The content of a ``torch.save`` file, CRCs checked (``zip_only``: as :func:`check_archive`), read weights-only
    (tensors and plain containers); a checkpoint of the removed network is refused."""
    check_archive(file, zip_only)
    try:
        content = torch.load(file, map_location="cpu", weights_only=True)
    except TORCH_DAMAGE as err:
        raise UserError(f"{file}: not a readable torch checkpoint ({' '.join(str(err).split())[:200]})") from None
    if isinstance(content, dict) and made_by_removed_network(content):
        raise UserError(
            f"{file}: made by the removed TransFuser network ({REMOVED_NETWORK}); lead-s2r trains LEAD's "
            "(lead_s2r.models.lead_driver.LeadDriver) only: train the run again with its recipe (docs/models.md)"
        )
    return content


def made_by_removed_network(checkpoint: dict[str, Any]) -> bool:
    """Whether a Lightning checkpoint's hyper_parameters name the removed network, or its state dict has its keys."""
    model = (checkpoint.get("hyper_parameters") or {}).get("model")
    if isinstance(model, dict) and model.get("class_path") == REMOVED_NETWORK:
        return True
    state = checkpoint.get("state_dict")
    return isinstance(state, dict) and any(str(key).startswith(REMOVED_NETWORK_KEYS) for key in state)
