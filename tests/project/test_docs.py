"""docs/api.md is generated from the docstrings and must be current; every public name is documented."""

import importlib.util
from pathlib import Path

DOCS = Path(__file__).resolve().parents[2] / "docs"


def _generator():
    spec = importlib.util.spec_from_file_location("gen_api", DOCS / "gen_api.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_api_reference_is_current():
    assert (DOCS / "api.md").read_text() == _generator().render(), "run: python docs/gen_api.py"


def test_every_public_name_documented_with_shapes():
    import gvnn_warp

    text = (DOCS / "api.md").read_text()
    for name in gvnn_warp.__all__:
        if name[0].isupper() or name in gvnn_warp._STAR_MODULES:
            continue
        assert f"### `{name}(" in text or name == "MIN_DEPTH", name
    assert "(undocumented)" not in text


def test_top_level_names_are_the_fronts():
    # gvnn_warp/__init__.py derives its torch-facing names from the front's sub-packages (importing it
    # stays free of torch): each name is the sub-package's own object, and nothing else is public
    import gvnn_warp
    from gvnn_warp import cameras, functional, nn

    front = [*functional.__all__, *nn.__all__, *cameras.__all__]
    assert len(front) == len(set(front)), "a name is exported by two front sub-packages"
    for module in (functional, nn, cameras):
        for name in module.__all__:
            assert getattr(gvnn_warp, name) is getattr(module, name), name
    extra = set(gvnn_warp.__all__) - set(front) - set(gvnn_warp._STAR_MODULES)
    assert extra == {"get_num_threads", "info", "set_num_threads"}


# ----------------------------------------------------------------------------- README code blocks

README = DOCS.parent / "README.md"
# the pages whose Python blocks are run and whose shell blocks are checked: the README and the guides
# of docs/ (datasets.md and vo_checkpoint.md show calls on files the reader has, api.md is generated)
PAGES = (README, *(DOCS / f"{name}.md" for name in ("install", "layers", "cameras", "odometry", "vo", "depth", "cli",
                                                     "performance", "architecture", "fusion")))


def readme_blocks(page: Path = README) -> list[tuple[str, str, bool]]:
    """(language, code, marked as the pure-Warp example) of every fenced block in the README (or page)."""
    import re

    text = page.read_text()
    blocks = []
    for m in re.finditer(r"^( *)```(\w+)\n(.*?)^\1```", text, re.S | re.M):
        indent = len(m.group(1))
        code = "\n".join(line[indent:] for line in m.group(3).splitlines())
        marked = text[: m.start()].rstrip().endswith("<!-- pure-warp-example -->")
        blocks.append((m.group(2), code, marked))
    return blocks


def test_readme_python_blocks_run(tmp_path, monkeypatch):
    """Every Python block runs as pasted (the pure-Warp one in a torch-free process, in
    test_pure_warp.py; the others here), in an empty folder (some write files)."""
    monkeypatch.chdir(tmp_path)
    blocks = [(code, marked) for lang, code, marked in readme_blocks() if lang == "python"]
    assert sum(marked for _, marked in blocks) == 1 and len(blocks) >= 2
    for page in PAGES:
        for lang, code, marked in readme_blocks(page):
            if lang == "python" and not marked:
                exec(compile(code, str(page), "exec"), {"__name__": "readme"})


def _commands(code: str) -> list[list[str]]:
    import re
    import shlex

    out = []
    for line in code.splitlines():
        line = line.split(" #")[0].strip()
        if loop := re.fullmatch(r"for (\w+) in [^;]+; do (.+); done", line):  # the loop's command, var = 1
            line = loop.group(2).replace("$" + loop.group(1), "1")
        if line and not line.startswith("#"):
            out += [shlex.split(part) for part in line.split("&&")]
    return out


def test_readme_shell_commands_are_valid():
    """The shell blocks are checked, not run (the set-up reinstalls, the demos take minutes; CI runs
    the quick start's set-up and test lines, which must be .ci/run's commands): each command's
    arguments are parsed by its own parser, pip's requirements must match pyproject.toml."""
    import tomllib
    from packaging.requirements import Requirement

    from gvnn_warp import cli
    from gvnn_warp.cli import depth as depth_cli
    from gvnn_warp.cli import vo

    ci = (DOCS.parent / ".ci" / "run").read_text()
    # the quick start's two lines (set-up and main job; tests) are exactly CI's two commands
    ci_commands = [line for line in ci.splitlines()
                   if line.strip() and not line.startswith(("#", "set ", "cd "))]
    quick_start = [code for lang, code, _ in readme_blocks() if lang == "bash"][0].strip().splitlines()
    assert quick_start == ci_commands, (quick_start, ci_commands)
    assert quick_start[1] == ".venv/bin/python -m pytest -q -n 2"
    assert "gvnn-warp render" in quick_start[0] and "gvnn-warp track" in quick_start[0]
    project = tomllib.loads((DOCS.parent / "pyproject.toml").read_text())["project"]
    torch_req = Requirement(project["optional-dependencies"]["torch"][0])
    seen = set()
    for lang, code, _ in [block for page in PAGES for block in readme_blocks(page)]:
        if lang != "bash":
            continue
        for line in code.splitlines():
            if "pytest" in line or ("pip install" in line and "gvnn-warp" in line):
                assert line.strip() in ci, f"README line not run by CI: {line}"
        for cmd in _commands(code):
            prog = cmd[0].removeprefix(".venv/bin/")
            if prog == "gvnn-warp":
                cli.build_parser().parse_args(cmd[1:])
            elif prog == "torchrun" and cmd[4] == "gvnn_warp.cli.depth":
                assert cmd[1:4] == ["--standalone", "--nproc_per_node=2", "-m"]
                parser = __import__("argparse").ArgumentParser()
                depth_cli.add_parser(parser.add_subparsers())
                parser.parse_args(["depth", *cmd[5:]])
            elif prog == "torchrun":
                assert cmd[1:4] == ["--standalone", "--nproc_per_node=2", "-m"] and cmd[4] == "gvnn_warp.cli.vo"
                parser = __import__("argparse").ArgumentParser()
                vo.add_arguments(parser)
                parser.parse_args(cmd[5:])
            elif prog in ("python", "python3") and cmd[1:3] == ["-m", "venv"]:
                assert cmd[3:] == [".venv"]
            elif prog == "python" and cmd[1:3] == ["-m", "pytest"]:
                pass  # checked against .ci/run above
            elif prog == "python" and cmd[1:3] == ["-m", "benchmarks.run"]:
                from benchmarks.run import build_parser

                build_parser().parse_args(cmd[3:])
            elif prog == "python" and cmd[1:3] == ["-m", "benchmarks.reprojection"]:
                from benchmarks.reprojection import build_parser as reprojection_parser

                reprojection_parser().parse_args(cmd[3:])
            elif prog == "pip" and cmd[1] == "install":
                for arg in cmd[2:]:
                    if arg.startswith("torch=="):
                        assert torch_req.specifier.contains(arg.split("==")[1]), (arg, torch_req)
                    elif arg.startswith(".["):
                        extras = arg[2:-1].split(",")
                        assert set(extras) <= set(project["optional-dependencies"]), arg
                    else:
                        assert arg in ("-e", ".", "--index-url", "https://download.pytorch.org/whl/cpu"), arg
            else:
                raise AssertionError(f"README command not checked by this test: {cmd}")
            seen.add(prog)
    assert {"gvnn-warp", "torchrun", "pip", "python"} <= seen


def _anchors(page: Path) -> set[str]:
    """GitHub's anchors of a markdown page's headings."""
    import re

    out = set()
    for line in page.read_text().splitlines():
        if m := re.match(r"#{1,6} (.*)", line):
            out.add(re.sub(r"[^\w\- ]", "", m.group(1).strip().lower()).replace(" ", "-"))
    return out


def test_relative_links_resolve():
    """Every relative link of the README, CONTRIBUTING.md and docs/*.md names a file of the repository
    (and, for a markdown page, one of its headings)."""
    import re

    root = DOCS.parent
    pages = [README, root / "CONTRIBUTING.md", *sorted(DOCS.glob("*.md"))]
    broken = []
    for page in pages:
        text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)  # not in code blocks
        for target in re.findall(r"\]\(([^)\s]+)\)", text):
            if re.match(r"[a-z]+:", target):
                continue  # https:, mailto:
            path, _, anchor = target.partition("#")
            file = (page.parent / path).resolve() if path else page
            if not file.exists() or (anchor and file.suffix == ".md" and anchor not in _anchors(file)):
                broken.append(f"{page.relative_to(root)}: {target}")
    assert not broken, broken
