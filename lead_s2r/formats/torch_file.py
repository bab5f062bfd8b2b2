"""``torch.save`` files (LEAD's ``model*.pth``, Lightning's ``.ckpt``) read with their damage named, not loaded.

torch reads its zip archive without checking the CRC32 of each member, so a flipped bit inside a tensor loads as
another weight and a model silently predicts something else. :func:`check_archive` checks every CRC first (about
0.3 s per 250 MB); :func:`load` then reads the file weights-only. Either failing is a :class:`UserError` naming the
file, whatever the damage made zipfile or torch raise.
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


def load(file: Path) -> Any:
    """The content of a ``torch.save`` file, CRCs checked, read weights-only (tensors and plain containers)."""
    check_archive(file)
    try:
        return torch.load(file, map_location="cpu", weights_only=True)
    except TORCH_DAMAGE as err:
        raise UserError(f"{file}: not a readable torch checkpoint ({' '.join(str(err).split())[:200]})") from None
