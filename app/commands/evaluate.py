"""``attune evaluate``: what other learners would have earned with a fleet's people, estimated
from the fleet's stored logs (``app.services.evaluation``; docs/operations.md §12)."""

from __future__ import annotations

import datetime as dt
from typing import TYPE_CHECKING, Annotated

import typer

from ._output import print_json, stderr_console, stdout_console
from ._setup import load_settings, open_database, tell

if TYPE_CHECKING:
    from rich.console import Console

    from app.services.evaluation import CandidateSpec, FleetEvaluation

__all__ = ["evaluate"]


def _when(text: str | None, option: str) -> dt.datetime | None:
    """A date (``2026-11-22``: its midnight UTC) or a time (``2026-11-22T08:00+01:00``; UTC
    when it names no offset)."""
    if text is None:
        return None
    try:
        at = dt.datetime.fromisoformat(text.strip())
    except ValueError:
        raise typer.BadParameter(
            f"{text!r} is not a date (2026-11-22) or a time (2026-11-22T08:00+01:00).",
            param_hint=option,
        ) from None
    return at if at.tzinfo is not None else at.replace(tzinfo=dt.UTC)


def _candidates(texts: list[str] | None) -> list[CandidateSpec]:
    from app.services.evaluation import parse_candidate

    if not texts:
        raise typer.BadParameter(
            "give at least one, for example --candidate dts --candidate 'hri:tau=0.005'.",
            param_hint="--candidate",
        )
    specs: list[CandidateSpec] = []
    for text in texts:
        try:
            spec = parse_candidate(text)
        except ValueError as exc:
            raise typer.BadParameter(str(exc), param_hint="--candidate") from None
        if spec.key not in {s.key for s in specs}:
            specs.append(spec)
    return specs


def _number(value: float | None) -> str:
    return "-" if value is None else f"{value:.2f}".replace("-", "−")


def _show(found: FleetEvaluation, per_person: bool, out: Console) -> None:
    from rich.table import Table

    logged = found.logged
    window = ""
    if found.since is not None or found.until is not None:
        start = "the start" if found.since is None else found.since.isoformat()
        end = "now" if found.until is None else found.until.isoformat()
        window = f", episodes from {start} to {end}"
    learners = ", ".join(f"{n} {name}" for name, n in found.learners.items())
    out.print(
        f"Fleet {found.fleet}: {found.people_counted} of {found.people} people, "
        f"{found.episodes} closed episodes{window}; estimator {found.estimator}, "
        f"95% intervals over people. The robots' learners now: {learners}.",
        markup=False,
    )
    table = Table("learner", "per encounter", "95% interval", "effective episodes", "meaning")
    now = logged.interval
    table.add_row(
        "what the robots do now",
        _number(logged.value),
        "-" if now is None else f"{_number(now.low)} to {_number(now.high)}",
        f"{logged.ess:.1f}",
        "what the logs show" if logged.enough else logged.reason,
    )
    for result in found.candidates:
        e = result.estimate
        table.add_row(
            result.spec.label,
            _number(e.value),
            "-"
            if e.interval is None
            else f"{_number(e.interval.low)} to {_number(e.interval.high)}",
            f"{e.ess:.1f}",
            result.verdict,
        )
    out.print(table)
    if per_person:
        people = Table(
            "person",
            "learner",
            "episodes",
            "now (mean)",
            *(c.spec.label for c in found.candidates),
        )
        for person in found.persons:
            people.add_row(
                person.user_id,
                person.algorithm,
                str(person.episodes),
                _number(person.mean_return),
                *(
                    _number(e.value) if e.enough else "not enough evidence"
                    for e in person.candidates
                ),
            )
        out.print(people)
    skipped = ", ".join(f"{n} {why}" for why, n in found.skipped.items())
    if skipped:
        out.print(f"Episodes not counted: {skipped}.", markup=False)
    for user_id, why in found.people_skipped:
        out.print(f"Person {user_id} left out: {why}", markup=False)


def evaluate(
    fleet: Annotated[str, typer.Option("--fleet", help="The fleet whose logs are read.")],
    candidate: Annotated[
        list[str] | None,
        typer.Option(
            "--candidate",
            metavar="ALGORITHM[:NAME=VALUE,...]",
            show_default=False,
            help="A learner to estimate, with the parameters that differ from its defaults: "
            "dts, hri:tau=0.005, dts-routine:samples=32,ask_unknown=false; default for the "
            "learner a person gets when nobody chooses one. prior=on or prior=off starts each "
            "person's candidate from the fleet's prior or fresh: dts:prior=off; "
            "current:prior=off is each person's own learner without the prior. Repeat for "
            "several.",
        ),
    ] = None,
    since: Annotated[
        str | None,
        typer.Option(
            "--since",
            metavar="DATE",
            show_default=False,
            help="Count the episodes that happened from then on (2026-11-01, or a time with its "
            "offset; UTC when it names none). The candidates still learn from all that came "
            "before.",
        ),
    ] = None,
    until: Annotated[
        str | None,
        typer.Option(
            "--until",
            metavar="DATE",
            show_default=False,
            help="Count the episodes that happened before then.",
        ),
    ] = None,
    estimator: Annotated[
        str | None,
        typer.Option(
            "--estimator",
            metavar="wpdis|wdr|dr|pdis",
            show_default=False,
            help="wpdis (weighted per-decision importance sampling), wdr (weighted doubly "
            "robust: wpdis with the candidate's own model as a control variate, which also "
            "speaks for what the logs seldom show), dr (doubly robust) or pdis (per-decision "
            "importance sampling); by default the one docs/method.md §17 recommends.",
        ),
    ] = None,
    per_person: Annotated[
        bool, typer.Option("--per-person", help="Also print each person's estimates.")
    ] = False,
    as_json: Annotated[bool, typer.Option("--json", help="Print one JSON document.")] = False,
    progress: Annotated[
        bool, typer.Option(help="Show a progress bar of the people done (on stderr).")
    ] = True,
) -> None:
    """Estimate what other learners would have earned with a fleet's people, from its stored
    logs, beside what the robots earn now (off-policy evaluation, docs/method.md §17).

    Each person's history is replayed into each candidate as the person's model was taught,
    and before every stored decision the candidate is asked how likely it would have been to do
    what the robot did; the closed episodes are then weighted by those odds. Nothing is changed.

    Prints a table: per candidate, its value per encounter with a 95% interval (a bootstrap over
    people), its effective number of episodes (how many of the logged episodes its estimate rests
    on), and what it means: more, less, or about the same as now (from the interval of the
    difference), or not enough evidence (too few episodes, or logs that rarely show what it
    would do). Exit 0; 2 for an unknown fleet, a bad candidate or option."""
    from app.learning.offpolicy import DEFAULT_ESTIMATOR, ESTIMATORS

    chosen = DEFAULT_ESTIMATOR if estimator is None else estimator
    if chosen not in ESTIMATORS:
        raise typer.BadParameter(
            f"{chosen!r}: one of {', '.join(ESTIMATORS)}.", param_hint="--estimator"
        )
    specs = _candidates(candidate)
    start, end = _when(since, "--since"), _when(until, "--until")
    if start is not None and end is not None and start >= end:
        raise typer.BadParameter("--since must come before --until.", param_hint="--since")

    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from app.errors import AppError
    from app.services import audit
    from app.services.context import ServiceContext
    from app.services.evaluation import evaluate_fleet

    settings = load_settings()
    ctx = ServiceContext.from_settings(settings)
    bar = Progress(
        TextColumn("[progress.description]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=stderr_console(),
        disable=not progress,
    )
    task = bar.add_task(f"people of {fleet}", total=None)

    def advance(done: int, total: int) -> None:
        bar.update(task, completed=done, total=total)

    with open_database(settings) as database:
        try:
            with bar:
                found = evaluate_fleet(
                    database,
                    ctx,
                    fleet,
                    specs,
                    since=start,
                    until=end,
                    estimator=chosen,
                    progress=advance,
                )
        except AppError as exc:
            tell(exc.detail, "red")
            raise typer.Exit(2) from None
        # The operator read every person's history: in the audit log, as the API's are.
        with database.transaction() as session:
            audit.record(
                session,
                audit.CLI,
                "evaluation.run",
                target=fleet,
                fleet=fleet,
                detail={
                    "candidates": [s.key for s in specs],
                    "since": None if start is None else start.isoformat(),
                    "until": None if end is None else end.isoformat(),
                    "estimator": chosen,
                    "people": found.people_counted,
                },
            )
    if as_json:
        print_json(found.to_dict())
        return
    _show(found, per_person, stdout_console())
