"""Every code example in the README and the guides runs, or says why it does not (issue 35).

The pages are read as Markdown; each fenced code block is one example:

- ```` ```python ```` blocks are executed in page order, all of a page's blocks in one namespace,
  with the page's own scratch folder as the working directory (so ``runs/sc`` in a guide lands
  there, never in the repository).
- ```` ```console ```` blocks (also ``bash``, ``sh``, ``shell``) are commands: each line that starts
  with ``$ `` (a trailing ``\\`` continues it; with no ``$`` line, every line that is not a
  comment) runs through ``bash`` in the same folder, the virtual environment's ``bin`` first on
  ``PATH``, and must exit 0. The lines after a command are its output as the page shows it: read
  by people, not compared (they hold timings).
- A block right after ``<!-- illustrative: REASON -->`` is not run: a Python block is compiled
  (a syntax error fails), and each ``evfuse`` command of a shell block is parsed by evfuse's own
  argument parser (:func:`fusion.cli.build_parser`), so a renamed or removed flag fails here too.
  The reason is required: it tells the maintainer why the example cannot run in the suite (it
  takes minutes, needs a GPU, ...).
- Every other block (``toml``, ``text``, ``json``, ...) is shown, not run; a block must name its
  language, so that a command cannot hide in an unmarked block.

The scratch folder also holds links to the repository's ``sweeps/``, ``scenes/`` and
``benchmarks/`` and, beside it as in a checkout, ``../shared`` where that exists: a command shown
as it would be typed in the repository's root runs unchanged. Generated pages
(``docs/generated/``, the reports ``evfuse reproduce`` wrote under ``docs/reproduce*/``) are not
guides and are skipped.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
SHELL_LANGUAGES = {"console", "bash", "sh", "shell"}
RUN_LANGUAGES = SHELL_LANGUAGES | {"python"}
#: folders of ``docs/`` whose pages a program wrote (not guides: their code is not examples)
GENERATED = ("generated", "reproduce", "reproduce_realistic")
#: what a page's scratch folder links to, as a checkout's root has it
LINKED = ("sweeps", "scenes", "benchmarks")
COMMAND_TIMEOUT_S = 300

_FENCE = re.compile(r"^(?P<indent>[ \t]*)(?P<fence>`{3,}|~{3,})(?P<info>[^`]*)$")
_MARKER = re.compile(r"^\s*<!--\s*illustrative:\s*(?P<reason>.*?)\s*-->\s*$")


@dataclass(frozen=True)
class Example:
    """One fenced code block of a page.

    Attributes
    ----------
    path : Path
        The page.
    line : int
        The line (1-based) of the block's opening fence.
    language : str
        The fence's language, lower case ("" when none is given).
    code : str
        The block's text, its indentation removed.
    illustrative : str or None
        The reason of an ``<!-- illustrative: REASON -->`` line right before the block.
    """

    path: Path
    line: int
    language: str
    code: str
    illustrative: str | None

    @property
    def where(self) -> str:
        return f"{_relative(self.path)}:{self.line}"


def _relative(path: Path) -> str:
    try:
        return str(path.relative_to(ROOT))
    except ValueError:
        return str(path)


def examples(path: Path, text: str | None = None) -> list[Example]:
    """The fenced code blocks of the Markdown page ``path``, in order."""
    lines = (path.read_text(encoding="utf-8") if text is None else text).splitlines()
    found = []
    i = 0
    while i < len(lines):
        match = _FENCE.match(lines[i])
        if not match:
            i += 1
            continue
        indent, fence = match["indent"], match["fence"]
        language = match["info"].strip().split(" ")[0].strip("{}.").lower()
        previous = next((lines[j] for j in range(i - 1, -1, -1) if lines[j].strip()), "")
        marker = _MARKER.match(previous)
        body = []
        j = i + 1
        while j < len(lines) and not (lines[j].strip().startswith(fence[0] * len(fence))
                                      and not lines[j].strip().strip(fence[0])):
            body.append(lines[j][len(indent):] if lines[j].startswith(indent) else lines[j])
            j += 1
        if j == len(lines):
            raise AssertionError(f"{_relative(path)}:{i + 1}: code block never closed")
        found.append(Example(path, i + 1, language, "\n".join(body) + "\n",
                             marker["reason"] if marker else None))
        i = j + 1
    return found


def commands(example: Example) -> list[str]:
    """The commands of a shell block: its ``$ `` lines (``\\`` continuing one), or every
    non-comment line of a block that has none."""
    lines = example.code.splitlines()
    prompted = any(line.startswith("$ ") for line in lines)
    found: list[str] = []
    continuing = False
    for line in lines:
        if continuing:
            found[-1] = found[-1][:-1].rstrip() + " " + line.strip()
        elif prompted and line.startswith("$ "):
            found.append(line[2:].strip())
        elif not prompted and line.strip() and not line.lstrip().startswith("#"):
            found.append(line.strip())
        else:
            continue
        continuing = found[-1].endswith("\\")
    return found


def pages() -> list[Path]:
    """The README and every guide under ``docs/`` (generated pages left out)."""
    docs = ROOT / "docs"
    guides = sorted(p for p in docs.rglob("*.md")
                    if p.relative_to(docs).parts[0] not in GENERATED)
    return [ROOT / "README.md", *guides]


def _evfuse_argv(command: str) -> list[str] | None:
    """The arguments of an ``evfuse`` command line (after environment assignments and
    ``time``), or None for any other program; a pipe or ``&&`` ends the command."""
    words = shlex.split(command, comments=True)
    for stop in ("|", "&&", ";", ">", "2>", "&"):
        if stop in words:
            words = words[:words.index(stop)]
    while words and (re.match(r"^[A-Za-z_][A-Za-z0-9_]*=", words[0]) or words[0] == "time"):
        words = words[1:]
    if not words or Path(words[0]).name != "evfuse":
        return None
    return words[1:]


def check_illustrative(example: Example) -> None:
    """Compile an illustrative Python block; parse each evfuse command of a shell one."""
    if not example.illustrative.strip():
        raise AssertionError(f"{example.where}: 'illustrative:' needs a reason")
    if example.language == "python":
        compile(example.code, example.where, "exec", dont_inherit=True)
        return
    from fusion.cli import build_parser

    for command in commands(example):
        argv = _evfuse_argv(command)
        if argv is None:
            continue
        try:
            build_parser().parse_args(argv)
        except SystemExit as exit_:
            raise AssertionError(f"{example.where}: evfuse's parser refuses the illustrative "
                                 f"command `{command}` (exit {exit_.code})") from None


def _scratch(folder: Path) -> Path:
    """A working folder laid out as a checkout's root, for one page."""
    work = folder / "work"
    work.mkdir()
    for name in LINKED:
        (work / name).symlink_to(ROOT / name, target_is_directory=True)
    shared = ROOT.parent / "shared"
    if shared.is_dir():
        (folder / "shared").symlink_to(shared, target_is_directory=True)
    return work


def run_page(path: Path, folder: Path) -> list[tuple[str, float]]:
    """Run every example of ``path`` in a scratch folder under ``folder``: the seconds each took
    (illustrative ones included, checked as the module's docstring says)."""
    work = _scratch(folder)
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(ROOT), env.get("PYTHONPATH")]))
    env.setdefault("MPLBACKEND", "Agg")
    namespace: dict = {"__name__": "__docs__"}
    timings = []
    cwd = Path.cwd()
    os.chdir(work)
    try:
        for example in examples(path):
            if example.language not in RUN_LANGUAGES:
                continue
            start = time.perf_counter()
            if example.illustrative is not None:
                check_illustrative(example)
            elif example.language == "python":
                exec(compile(example.code, example.where, "exec", dont_inherit=True), namespace)
            else:
                for command in commands(example):
                    done = subprocess.run(["bash", "-c", command], cwd=work, env=env,
                                          capture_output=True, text=True,
                                          timeout=COMMAND_TIMEOUT_S)
                    if done.returncode != 0:
                        raise AssertionError(
                            f"{example.where}: `{command}` exited {done.returncode}:\n"
                            f"{done.stdout[-2000:]}{done.stderr[-4000:]}")
            timings.append((example.where, time.perf_counter() - start))
    finally:
        os.chdir(cwd)
    return timings


# --- the harness on planted pages -------------------------------------------------------------

PLANTED = """# A page

```python
x = 1
```

<!-- illustrative: renders for ten minutes -->

```console
$ evfuse simulate slider_close --duration 0.5 \\
    --out runs/sc
written to runs/sc
```

- a list item
  ```toml
  [camera]
  ```

```
no language
```
"""


def test_the_reader_finds_each_block_its_language_and_marker(tmp_path):
    found = examples(tmp_path / "page.md", PLANTED)
    assert [(e.line, e.language, e.illustrative) for e in found] == [
        (3, "python", None), (9, "console", "renders for ten minutes"), (16, "toml", None),
        (20, "", None)]
    assert found[2].code == "[camera]\n"
    assert commands(found[1]) == ["evfuse simulate slider_close --duration 0.5 --out runs/sc"]


def test_commands_without_prompts_are_every_line_but_comments(tmp_path):
    (block,) = examples(tmp_path / "p.md", "```bash\n# set up\nmake demo\nmake test\n```\n")
    assert commands(block) == ["make demo", "make test"]


def test_an_illustrative_command_with_a_flag_evfuse_lacks_fails(tmp_path):
    text = ("<!-- illustrative: slow -->\n```console\n"
            "$ evfuse simulate slider_close --duration 0.5 --out sc --no-such-flag 3\n```\n")
    (block,) = examples(tmp_path / "p.md", text)
    with pytest.raises(AssertionError, match="refuses the illustrative command"):
        check_illustrative(block)
    good = examples(tmp_path / "p.md", text.replace(" --no-such-flag 3", ""))[0]
    check_illustrative(good)


def test_an_illustrative_marker_needs_a_reason_and_python_must_compile(tmp_path):
    (empty,) = examples(tmp_path / "p.md", "<!-- illustrative:  -->\n```python\nx = 1\n```\n")
    with pytest.raises(AssertionError, match="needs a reason"):
        check_illustrative(empty)
    (broken,) = examples(tmp_path / "p.md",
                         "<!-- illustrative: slow -->\n```python\nx = (1\n```\n")
    with pytest.raises(SyntaxError):
        check_illustrative(broken)


def test_a_page_s_dataclass_runs_as_in_a_script(tmp_path):
    """The harness's own ``from __future__ import annotations`` does not leak into the pages'
    code (a dataclass there would then see string annotations it cannot resolve)."""
    page = tmp_path / "page.md"
    page.write_text("```python\nfrom dataclasses import dataclass\n\n@dataclass\nclass P:\n"
                    "    x: int = 1\n\nassert P.__annotations__['x'] is int\n```\n",
                    encoding="utf-8")
    assert len(run_page(page, tmp_path)) == 1


def test_a_failing_example_names_its_page_and_line(tmp_path):
    page = tmp_path / "page.md"
    page.write_text("# p\n\n```python\nvalue = 41\n```\n\n```console\n$ test -d sweeps\n"
                    "$ python -c 'raise SystemExit(3)'\n```\n", encoding="utf-8")
    with pytest.raises(AssertionError, match=r"page.md:7: .* exited 3"):
        run_page(page, tmp_path)


def test_the_docs_have_examples_to_run():
    """The harness reads real pages (so that a path mistake cannot make it pass on nothing)."""
    assert (ROOT / "README.md") in pages()
    runnable = [e for p in pages() for e in examples(p) if e.language in RUN_LANGUAGES]
    assert len(runnable) >= 20, [e.where for e in runnable]


# --- the pages ----------------------------------------------------------------------------------

@pytest.mark.parametrize("page", pages(), ids=lambda p: _relative(p))
def test_every_block_names_its_language(page):
    unnamed = [e.where for e in examples(page) if not e.language]
    assert not unnamed, f"code blocks without a language (use text for output): {unnamed}"


@pytest.mark.parametrize("page", pages(), ids=lambda p: _relative(p))
def test_page_examples_run(page, tmp_path):
    timings = run_page(page, tmp_path)
    print(f"{_relative(page)}: {len(timings)} examples in {sum(t for _, t in timings):.1f} s")
