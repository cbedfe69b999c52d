"""The prediction as the analysis asks for it: a run's system file -> what it expects (model.Expected)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

from ..model import Expected
from ..sysfile.system import loads
from ..sysfile.yamlfile import SystemFileError
from .predict import predict


def predictor(path: Path) -> Callable[[str], Expected]:
    """What analysis/measure/predicted.py asks for: a run's system file (the text its config
    carries, overrides applied) -> its prediction's figures as report.json rounds them,
    validated as if it were the file at PATH (a `samples:` file is looked for beside it);
    ValueError says why it cannot be."""
    def prediction(text: str) -> Expected:
        try:
            return Expected.from_json(predict(loads(text, path)).to_json())
        except SystemFileError as e:
            raise ValueError(str(e)) from None
    return prediction
