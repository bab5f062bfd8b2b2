"""Verbs that score: ``score`` (open loop) and ``carla-metrics`` (closed-loop results)."""

import argparse
import json
from pathlib import Path
from typing import Any

from lead_s2r.cli.common import add_executor_arguments, removed_on_failure
from lead_s2r.errors import UserError
from lead_s2r.registry import SCORER_GROUP, load


def cmd_score(args: argparse.Namespace) -> int:
    from lead_s2r.processes import make_executor
    from lead_s2r.scoring.run import planner_predictions, score_predictions
    from lead_s2r.scoring.scores_file import SCORES_JSON, SCORES_TABLE

    options: dict[str, Any] = {"allow_missing": not args.strict}
    for option in args.option:
        name, equals, value = option.partition("=")
        if not name or not equals:
            raise UserError(f"--option {option!r}: expected KEY=VALUE, e.g. --option floor=4")
        try:
            options[name] = json.loads(value)  # numbers, booleans, lists
        except json.JSONDecodeError:
            options[name] = value
    if args.reference_cache:
        options["reference_cache"] = args.reference_cache
    scorer_module = load(args.metric, SCORER_GROUP).__module__  # the workers' forkserver imports it once
    executor = make_executor(args.workers, args.executor, args.address, preload=[scorer_module])
    data, out = [Path(folder) for folder in args.data], Path(args.out)
    with removed_on_failure(out):
        predictions = Path(args.predictions) if args.predictions else None
        if predictions is None:
            path = out / f"predictions-{args.planner}.parquet"
            predictions = planner_predictions(args.planner, data, path, args.split)
        selection = {"split": args.split, "tag": args.tag}
        summary = score_predictions(args.metric, predictions, data, out, executor=executor, **selection, **options)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        from rich.console import Console

        from lead_s2r.report.score_summary import score_table

        Console().print(score_table(summary))
        print(f"wrote {out / SCORES_JSON} and {SCORES_TABLE} ({summary['seconds']:.1f} s)")
    return 0


def cmd_carla_metrics(args: argparse.Namespace) -> int:
    from lead_s2r.scoring.carla_leaderboard import carla_metrics

    summary = carla_metrics(args.results, args.benchmark, Path(args.out), args.routes)
    print(json.dumps(summary["aggregates"], indent=2))
    return 0


def add_verbs(verbs: Any) -> None:
    sub = verbs.add_parser("score", help="score predictions open-loop")
    sub.add_argument("--metric", required=True, help=f"one of the {SCORER_GROUP} entry points")
    source = sub.add_mutually_exclusive_group(required=True)
    source.add_argument("--predictions", help="predictions.parquet of a model")
    source.add_argument("--planner", choices=("human", "constant-velocity"), help="score a model-free planner instead")
    sub.add_argument("--data", required=True, nargs="+", help="converted folder(s)")
    sub.add_argument("--out", required=True)
    sub.add_argument("--option", action="append", default=[], metavar="KEY=VALUE", help="scorer configuration")
    sub.add_argument("--split", default=None, help="score only this split of --data (e.g. val)")
    sub.add_argument(
        "--tag", default=None, help="score only the samples with this tag (e.g. scene_filter:pedestrians_ahead)"
    )
    sub.add_argument("--strict", action="store_true", help="a sample without a prediction is an error")
    sub.add_argument("--json", action="store_true", help="print scores.json instead of the summary table")
    sub.add_argument("--reference-cache", default=None, help="PDMS: folder caching PDM-Closed references per sample")
    add_executor_arguments(sub, "processes scoring on this machine (the scores are the same)")
    sub.set_defaults(run=cmd_score)

    sub = verbs.add_parser("carla-metrics", help="CARLA leaderboard 2.0 results -> DS, RC, IS, SR, NDS, per 100 km")
    sub.add_argument("results", nargs="+", help="results JSON files (one per seed or route batch)")
    sub.add_argument("--benchmark", required=True, choices=["bench2drive", "longest6", "town13"])
    sub.add_argument("--out", required=True)
    sub.add_argument("--routes", default=None, help="the benchmark's routes XML, to name the missing routes")
    sub.set_defaults(run=cmd_carla_metrics)
