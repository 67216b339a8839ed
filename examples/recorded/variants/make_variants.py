"""Write the shipped potato record (../potato_tuy.csv) the ways lab scripts and scopes write files.

Each file is fitted by the config of the same name (one reader option at most), as
docs/recorded-data.md shows. Deterministic: it reproduces the files byte for byte.

    python examples/recorded/variants/make_variants.py [--out FOLDER]
"""
from __future__ import annotations

import argparse
from pathlib import Path

HERE = Path(__file__).resolve().parent


def rows() -> list[list[str]]:
    lines = (HERE.parent / "potato_tuy.csv").read_text().splitlines()
    return [line.split(",") for line in lines[1:]]


def write(folder: Path) -> list[Path]:
    r = rows()
    files = {
        "renamed.csv": ["time,excitation,response"] + [",".join(x) for x in r],
        "semicolon.csv": ["t;u;y"] + [";".join(x) for x in r],
        "decimal_comma.csv": ["t;u;y"] + [";".join(v.replace(".", ",") for v in x) for x in r],
        "units_row.csv": ["t,u,y", "s,N,N"] + [",".join(x) for x in r],
        "preamble.csv": ["potato slice 3 cm, PRBS burst", "operator: lab 2", "t,u,y"] + [",".join(x) for x in r],
        "headerless.txt": [" ".join(x) for x in r],
        "commented.tsv": ["# potato slice, written by a lab script", "t [s]\tu [N]\ty [N]"]
        + ["\t".join(x) for x in r],
        "scope_u.csv": ["time,value"] + [f"{x[0]},{x[1]}" for x in r],
        "scope_y.csv": ["time,value"] + [f"{x[0]},{x[2]}" for x in r],
    }
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for name, lines in files.items():
        path = folder / name
        path.write_text("\n".join(lines) + "\n")
        out.append(path)
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=HERE)
    print(f"wrote {len(write(ap.parse_args().out))} files")
