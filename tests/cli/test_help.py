"""``--help`` shows every default, read from where it is written once (the parser or OptimizeSettings)."""

import argparse
import dataclasses
import sys
from pathlib import Path

import pytest

from cmrt.cli.commands import build_parser, help_reference
from cmrt.optimize.settings import FAMILY_SIGMA0, STALE_AFTER_S, OptimizeSettings
from cmrt.service.jobs import budget_min_evals


def _verbs() -> dict[str, argparse.ArgumentParser]:
    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return dict(sub.choices)


@pytest.mark.parametrize("verb", sorted(_verbs()))
def test_every_option_with_a_default_shows_it(verb):
    sub = _verbs()[verb]
    text = " ".join(sub.format_help().split())
    missing = [a.option_strings[0] for a in sub._actions
               if a.option_strings and a.default not in (None, False, argparse.SUPPRESS)
               and f"default: {a.default}" not in text]
    assert missing == []


def test_the_optimizer_options_default_to_its_settings():
    settings = OptimizeSettings()
    args = build_parser().parse_args(["optimize", "bend"])
    for name in ("seed", "max_evals", "popsize", "stall_generations"):
        assert getattr(args, name) == getattr(settings, name), name
    assert args.sigma0 is None  # the settings' 0.5 from the zero CMRT, FAMILY_SIGMA0 from a known one (submit)
    assert args.min_evals is None  # the settings' 700, or the budget if smaller (jobs.budget_min_evals)
    assert budget_min_evals(args.max_evals, args.min_evals) == settings.min_evals
    assert args.family_sigma0 == FAMILY_SIGMA0
    assert build_parser().parse_args(["worker"]).stale_after == STALE_AFTER_S
    submitted = build_parser().parse_args(["submit", "bend"])
    assert {f.name for f in dataclasses.fields(settings)} >= {"seed", "max_evals"} and submitted.seed == settings.seed


@pytest.mark.skipif(sys.version_info[:2] != (3, 11), reason="argparse lays help out differently in other Pythons")
def test_the_cli_reference_in_docs_is_every_verbs_help():
    """docs/reference/cli.md is what ``cmrt VERB --help`` prints, verb for verb (tools/cli_reference.py)."""
    doc = (Path(__file__).resolve().parents[2] / "docs" / "reference" / "cli.md").read_text()
    assert doc == help_reference(), "docs/reference/cli.md is out of date: python tools/cli_reference.py"
    for verb in _verbs():
        assert f"## cmrt {verb}\n" in doc
