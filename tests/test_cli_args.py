"""Argument types shared by the commands."""

from __future__ import annotations

import argparse

import pytest

from dashtraj.cli._args import nms_iou, seed_list


@pytest.mark.parametrize(("text", "seeds"), [
    ("0-4", (0, 1, 2, 3, 4)),
    ("3,8,11", (3, 8, 11)),
    ("5", (0, 1, 2, 3, 4)),
    ("7-7", (7,)),
    (" 2-3 ", (2, 3)),
])
def test_seed_list(text, seeds):
    assert seed_list(text) == seeds


@pytest.mark.parametrize("text", ["0", "-1", "4-2", "1,1", "a", "1-2-3", "1,-2", ""])
def test_seed_list_refuses(text):
    with pytest.raises(argparse.ArgumentTypeError):
        seed_list(text)


def test_nms_iou():
    assert nms_iou("0.45") == 0.45 and nms_iou("1") == 1.0
    assert nms_iou("none") is None and nms_iou(" None ") is None
    for bad in ("0", "-0.1", "1.5", "nan", "x", ""):
        with pytest.raises(argparse.ArgumentTypeError):
            nms_iou(bad)


def test_every_localizer_help_names_the_library_localizers():
    """The --localizer help strings are written out (building them from
    `LOCALIZERS` would import the road map on every command's start): each must
    name every one of the library's localizers, and its default must be one."""
    import re

    from dashtraj.cli import build_parser
    from dashtraj.perception.localize import LOCALIZERS

    seen = 0
    stack = [build_parser()]
    while stack:
        parser = stack.pop()
        for action in parser._actions:
            if isinstance(action, argparse._SubParsersAction):
                stack.extend(action.choices.values())
            elif "--localizer" in action.option_strings:
                seen += 1
                named = set(re.findall(r"\b[a-z]+\b", action.help.split("(default")[0]))
                assert set(LOCALIZERS) <= named, action.help
                # a default of None stands for the one the help names (`sightings` tells
                # whether the user chose the option: it applies to the camera pipeline only)
                default = action.default or re.search(r"\(default (\w+)\)", action.help)[1]
                assert default in LOCALIZERS
    assert seen >= 3  # perceive, sightings, experiments (and demo)
