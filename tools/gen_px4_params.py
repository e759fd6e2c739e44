"""Write ``px4_params.json`` from QGroundControl's ``src/FirmwarePlugin/PX4/PX4ParameterFactMetaData.xml``.

    python3 tools/gen_px4_params.py PX4ParameterFactMetaData.xml --source "QGC commit ..."

Only data is taken: name, type, default, min, max, unit, reboot_required; never the descriptions. Groups
marked ``no_code_generation`` (UAVCAN node settings with lower-case names, not PX4 parameters) are left out.
A missing bound becomes the type's limit (INT32: the values a float32 field carries through pymavlink) (a bitmask: all its bits; an enumeration without bounds: its codes'
range); a default outside its bounds widens them (the firmware starts with its default).
"""

from __future__ import annotations

import argparse
import json
import math
import xml.etree.ElementTree as ET
from pathlib import Path

INT32_MIN, INT32_MAX = -4194304, 2139095040
"""The INT32 values that travel bytewise in PARAM_VALUE's float through every client: below -4194304 and above
2139095040 lie float32 signalling-NaN bit patterns, which a Python float (pymavlink) turns quiet."""
FLOAT32_MAX = 3.4028234663852886e38
NAME_MAX = 16
"""MAVLink's param_id is 16 characters."""


def _num(text: str | None) -> float | None:
    if text is None or not text.strip():
        return None
    try:
        v = float(text.strip())
    except ValueError:
        return None
    return v if math.isfinite(v) else None


def _compact(v: float, is_int: bool) -> float | int:
    if is_int:
        return int(v)
    return int(v) if v == int(v) and abs(v) < 1e15 else v


def rows(xml_text: str) -> list[list[object]]:
    root = ET.fromstring(xml_text)
    out: dict[str, list[object]] = {}
    for group in root.iter("group"):
        if group.get("no_code_generation") == "true":
            continue
        for p in group.iter("parameter"):
            name = p.get("name", "")
            kind = p.get("type", "")
            if not name or len(name) > NAME_MAX or kind not in ("INT32", "FLOAT"):
                continue
            is_int = kind == "INT32"
            default = _num(p.get("default")) or 0.0
            lo, hi = _num(p.findtext("min")), _num(p.findtext("max"))
            if is_int and (lo is None or hi is None):
                codes = [c for v in p.iter("value") if (c := _num(v.get("code"))) is not None]
                bits = [b for v in p.iter("bit") if (b := _num(v.get("index"))) is not None]
                if bits:
                    lo = 0.0 if lo is None else lo
                    hi = float(2 ** (int(max(bits)) + 1) - 1) if hi is None else hi
                elif codes:
                    lo = min(codes) if lo is None else lo
                    hi = max(codes) if hi is None else hi
            if lo is None:
                lo = float(INT32_MIN) if is_int else -FLOAT32_MAX
            if hi is None:
                hi = float(INT32_MAX) if is_int else FLOAT32_MAX
            if is_int:
                lo, hi = max(lo, INT32_MIN), min(hi, INT32_MAX)
            lo, hi = min(lo, default), max(hi, default)
            unit = (p.findtext("unit") or "").strip()
            reboot = 1 if (p.findtext("reboot_required") or "").strip() == "true" else 0
            out[name] = [
                name,
                "I" if is_int else "F",
                _compact(default, is_int),
                _compact(lo, is_int),
                _compact(hi, is_int),
                unit,
                reboot,
            ]
    return [out[n] for n in sorted(out)]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("xml", type=Path)
    ap.add_argument("--source", required=True, help="where the XML came from (repository, commit, date)")
    ap.add_argument(
        "--out",
        type=Path,
        default=Path(__file__).resolve().parents[1] / "harness/autopilot/params_data/px4_params.json",
    )
    a = ap.parse_args()
    table = rows(a.xml.read_text(encoding="utf-8"))
    lines = ",\n".join("  " + json.dumps(r, ensure_ascii=False) for r in table)
    a.out.write_text('{"source": ' + json.dumps(a.source) + ',\n "params": [\n' + lines + "\n]}\n", encoding="utf-8")
    print(f"{len(table)} parameters -> {a.out}")


if __name__ == "__main__":
    main()
