"""Camera metadata, ICC profile and chromaticities of clisp's outputs, against the raw (issue 14).

    python tools/check_metadata.py RAW [RAW ...] [--work DIR]

For each raw: ``clisp process RAW -o X.tif`` and ``-o X.exr`` (the whole command), then reads the
raw file and both outputs with OpenImageIO (its TIFF reader opens DNG and KDC files; LibRaw is not
in the PyPI wheel) and prints Make and Model of each, whether they are equal, the TIFF's ICC
profile size and description, and the EXR's chromaticities and Make. Exit 1 if Make or Model
differ or the profile or chromaticities are missing.
"""
from __future__ import annotations

import argparse
import subprocess
from pathlib import Path

import toolkit


def spec_of(path: Path):
    import OpenImageIO as oiio
    image = oiio.ImageInput.open(str(path))
    if image is None:
        raise SystemExit(f"{path}: OpenImageIO cannot open it: {oiio.geterror()}")
    spec = image.spec()
    image.close()
    return spec


def icc_description(blob: bytes) -> str:
    """The 'desc' tag's text of an ICC profile (v2 textDescriptionType or v4 mluc), or ''."""
    count = int.from_bytes(blob[128:132], "big")
    for k in range(count):
        entry = blob[132 + 12 * k:144 + 12 * k]
        if entry[:4] == b"desc":
            offset, size = int.from_bytes(entry[4:8], "big"), int.from_bytes(entry[8:12], "big")
            text = blob[offset:offset + size]
            if text[:4] == b"mluc":                       # ICC v4: the first record, UTF-16BE
                length, start = int.from_bytes(text[20:24], "big"), int.from_bytes(text[24:28], "big")
                return text[start:start + length].decode("utf-16-be")
            length = int.from_bytes(text[8:12], "big")
            return text[12:12 + length].rstrip(b"\0").decode("latin-1")
    return ""


def check(raw: Path, work: Path) -> bool:
    ok = True
    outputs = {ext: work / f"{raw.stem}.{ext}" for ext in ("tif", "exr")}
    for out in outputs.values():          # this checkout's clisp, as a process of its own
        subprocess.run(toolkit.clisp_cmd("process", str(raw), "-o", str(out)), check=True,
                       env=toolkit.repo_env(toolkit.REPO), cwd=toolkit.NEUTRAL_CWD)
    source = spec_of(raw)
    make, model = source.get_string_attribute("Make"), source.get_string_attribute("Model")
    print(f"{raw.name}: raw Make {make!r}, Model {model!r}")
    for ext, out in outputs.items():
        spec = spec_of(out)
        same = spec.get_string_attribute("Make") == make and spec.get_string_attribute("Model") == model
        ok &= same and bool(make)
        line = (f"  {ext}: Make {spec.get_string_attribute('Make')!r}, Model "
                f"{spec.get_string_attribute('Model')!r} ({'equal' if same else 'DIFFERENT'})")
        if ext == "tif":
            icc = spec.getattribute("ICCProfile")
            blob = bytes(icc) if icc is not None else b""
            ok &= len(blob) > 0
            line += f", ICC {len(blob)} bytes {icc_description(blob)!r}" if blob else ", no ICC profile"
        else:
            chroma = spec.getattribute("chromaticities")
            ok &= chroma is not None
            line += f", chromaticities {tuple(round(float(v), 4) for v in chroma) if chroma else None}"
        print(line)
    return ok


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("raws", nargs="+", type=toolkit.resolved_path)
    toolkit.add_work_option(ap, "the outputs")
    args = ap.parse_args()
    with toolkit.work_folder(args.work, "check_metadata-") as work:
        results = [check(raw, work) for raw in args.raws]
    return 0 if all(results) else 1


if __name__ == "__main__":
    raise SystemExit(main())
