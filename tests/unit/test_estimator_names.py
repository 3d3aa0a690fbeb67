"""Every estimator the learning core offers is one an evaluation may ask for, and the console
has words for each: the lists are written apart and must not drift."""

from __future__ import annotations

import typing

from app.console.views import estimator_words
from app.learning.offpolicy import DEFAULT_ESTIMATOR, ESTIMATORS, MODEL_ESTIMATORS
from app.schemas.evaluations import EvaluationIn


def test_the_api_takes_exactly_the_cores_estimators() -> None:
    annotation = EvaluationIn.model_fields["estimator"].annotation
    literal = next(a for a in typing.get_args(annotation) if a is not type(None))
    assert set(typing.get_args(literal)) == set(ESTIMATORS)
    assert DEFAULT_ESTIMATOR in ESTIMATORS
    assert set(MODEL_ESTIMATORS) <= set(ESTIMATORS)


def test_the_console_names_every_estimator_in_words() -> None:
    for estimator in ESTIMATORS:
        words = estimator_words(estimator)
        assert words != estimator
        assert f"({estimator})" in words
