"""The README's examples run as written, against the files the project ships (issue 20)."""

from __future__ import annotations

import itertools
import re
import shlex
from pathlib import Path

import httpx
import pytest
from typer.testing import CliRunner

from schemas import Detection
from schemas.grasp import GraspPlan
from service.cli import app
from service.http import Settings
from tests.service.test_http import running_server

ROOT = Path(__file__).resolve().parents[2]
README = (ROOT / "README.md").read_text()


def shell_commands(text: str) -> list[str]:
    """The commands of the README's ``sh`` blocks, continuation lines joined."""
    commands = []
    for block in re.findall(r"```sh\n(.*?)```", text, flags=re.DOTALL):
        for command in block.replace("\\\n", " ").splitlines():
            command = re.sub(r"\s+#.*$", "", command).strip()  # trailing comments
            if command:
                commands.append(command)
    return commands


def grasp_requests() -> list[list[str]]:
    return [
        shlex.split(command)
        for command in shell_commands(README)
        if command.startswith("curl ") and "/v1/grasp" in command
    ]


def multipart(words: list[str]) -> tuple[dict, dict]:
    """curl's ``-F name=@file`` and ``-F name=value`` as httpx ``files`` and ``data``."""
    files, data = {}, {}
    for flag, value in itertools.pairwise(words):
        if flag != "-F":
            continue
        name, _, given = value.partition("=")
        if given.startswith("@"):
            path = ROOT / given[1:]
            files[name] = (path.name, path.read_bytes())
        else:
            data[name] = given
    return files, data


def test_the_readme_has_grasp_examples() -> None:
    assert len(grasp_requests()) == 2


def test_the_readme_grasp_requests_succeed_as_written() -> None:
    with running_server(Settings(workers=1, zenoh=False)) as base:
        for words in grasp_requests():
            url = next(word for word in words if word.startswith("http://"))
            files, data = multipart(words)
            response = httpx.post(
                url.replace("http://127.0.0.1:8000", base), files=files, data=data
            )
            assert response.status_code == 200, (words, response.text)
            plan = GraspPlan.model_validate_json(response.text)
            assert plan.within_workspace, plan.refusal


@pytest.mark.parametrize(
    "needle", ["dlo detect docs/examples/cables.jpg --segmentation hsv", "dlo ur3 plan"]
)
def test_the_readme_command_lines_run_as_written(needle: str, monkeypatch) -> None:
    monkeypatch.chdir(ROOT)
    (command,) = [line for line in shell_commands(README) if needle in line]
    words = shlex.split(command)
    assert words[0] == ".venv/bin/dlo"
    result = CliRunner().invoke(app, words[1:], prog_name="dlo")
    assert result.exit_code == 0, result.output
    if words[1] == "detect":
        detection = Detection.model_validate_json(result.stdout)
        assert len(detection.chains) == 1  # the orange cable alone
    else:
        assert GraspPlan.model_validate_json(result.stdout).within_workspace


def test_the_readme_exit_codes_say_ctrl_c_is_130() -> None:
    row = next(line for line in README.splitlines() if line.startswith("| 130 |"))
    assert "Ctrl-C" in row
