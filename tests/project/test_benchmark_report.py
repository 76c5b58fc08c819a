"""The report of ``python -m benchmarks.run`` (formatting only: no timing here): every target is
explained, no infinite limits, no repeated rows, no empty sections."""

import re

import pytest

run = pytest.importorskip("benchmarks.run")


def _row(number, what, limit):
    return {"target": number, "what": what, "ours_ms": 2.0, "peer": "kornia", "peer_ms": 4.0, "ratio": 0.5,
            "limit": limit, "met": None if limit is None else 0.5 <= limit, "note": ""}


def _report(with_subprocess=True):
    sc = {"B": 8, "H": 240, "W": 320, "ours": 20.0, "grid_sample": 15.0, "kornia": 50.0}
    report = {
        "machine": {"cpu": "cpu", "nproc": 2, "python": "3", "torch": "2", "warp": "1", "kornia": "0",
                    "load_average": (1.0, 1.0, 1.0), "load_average_end": (1.0, 1.0, 1.0)},
        "repeats": 3, "quick": True, "started": "t0", "finished": "t1",
        "targets": [_row(1, "a vs b", 1.0), _row(1, "a vs c (info)", None), _row(3, "so3", 0.5), _row(6, "tiny", 1.0)],
        "scaling": {"image_size": [{**sc, "H": 60, "W": 80}, sc], "batch": [{**sc, "B": 1}, sc]},
        "kernels": [],
    }
    if with_subprocess:
        io = {"peak_bytes": 2**25, "io_bytes": 2**24, "ratio": 2.0, "method": "VmHWM"}
        report["memory"] = {"ours": io, "kornia": io}
        report["startup"] = {"warm": {"import_and_first_call_s": 0.7, "torch_import_s": 1.1}}
    return report


@pytest.mark.parametrize("with_subprocess", [True, False])
def test_report_explains_targets_without_inf_duplicates_or_empty_headings(with_subprocess, monkeypatch):
    monkeypatch.setattr(run.kernel_bench, "format_rows", lambda rows, threads: "| kernel |\n|---|\n| so3_exp |")
    text = run.fmt_summary(_report(with_subprocess), 2)
    assert not re.search(r"\binf\b", text)
    for n in (1, 3, 6) + ((4, 5) if with_subprocess else ()):
        assert f"\n{n}. {run.TARGETS[n]}." in text  # what each target measures
    table_rows = [line for line in text.splitlines() if line.startswith("| ") and not line.startswith("| #")]
    assert len(table_rows) == len(set(table_rows)), "a row is repeated"
    sections = re.split(r"^#+ .*$", text, flags=re.M)[1:]
    assert all(s.strip() for s in sections), "a heading without content"
    assert "(info)" in text.split("Measured for information")[1]  # info rows apart from the targets


def test_scaling_measures_each_configuration_once(monkeypatch):
    calls = []

    def fake_interleaved(cases, repeats, warmup=1):
        calls.append(len(cases))
        return {"ours": 1.0, "grid_sample": 1.0, "kornia": 1.0}

    monkeypatch.setattr(run, "interleaved", fake_interleaved)
    monkeypatch.setattr(run, "wfd_cases", lambda *a, **k: [None, None, None])
    monkeypatch.setattr(run, "_progress", lambda msg: None)

    class Args:
        quick = True

    sc = run.scaling(Args, 3)
    assert len(calls) == 3  # (8, 60x80), (8, 240x320) in both series, (1, 240x320)
    assert sc["image_size"][1] is sc["batch"][1]
