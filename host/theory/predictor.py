"""The prediction as the analysis asks for it: a run's system file -> its prediction's JSON."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

from ..sysfile.system import loads
from ..sysfile.yamlfile import SystemFileError
from .predict import predict


def predictor(path: Path) -> Callable[[str], dict[str, Any]]:
    """What analysis/measure/predicted.py asks for: a run's system file (the text its config
    carries, overrides applied) -> its prediction's JSON, validated as if it were the file at
    PATH (a `samples:` file is looked for beside it); ValueError says why it cannot be."""
    def prediction(text: str) -> dict[str, Any]:
        try:
            return predict(loads(text, path)).to_json()
        except SystemFileError as e:
            raise ValueError(str(e)) from None
    return prediction
