"""The abi3 win_amd64 wheel, cross-built on Linux (make wheel-windows), and the checks it must pass.

    python scripts/windows_wheel.py assemble PURE_WHEEL CORE_PYD OPENBLAS_DLL DIST_DIR
        PURE_WHEEL (setup.py's files and metadata without the extension: SKINKIT_WITHOUT_EXTENSION=1) plus the
        MinGW-built skinkit/_core.pyd and scipy-openblas32's DLL beside it, tagged cp311-abi3-win_amd64. Python
        (3.8+) loads an extension's DLLs from the extension's own folder, so the DLL needs no loader patch.
    python scripts/windows_wheel.py check WHEEL
        objdump -p of the wheel's _core.pyd: it exports PyInit__core and nothing else, and imports python3.dll (the
        stable ABI, never python3XY.dll), the bundled OpenBLAS DLL and system DLLs only; the OpenBLAS DLL imports
        system DLLs only. Exits non-zero naming what is wrong.
    python scripts/windows_wheel.py through-pipe [NAME=VALUE ...] COMMAND ...
        Runs COMMAND (env(1) style) with its output passed on through a pipe, and exits with its status: Windows
        CPython under Wine cannot start its standard streams when they are regular files (a CI log), only pipes
        and terminals.
"""
import base64
import hashlib
import os
import re
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

TAG = "cp311-abi3-win_amd64"
OBJDUMP = "x86_64-w64-mingw32-objdump"
# What every Windows 10+ machine has: the kernel, the C runtime (msvcrt, or the UCRT through its api sets).
SYSTEM_DLL = re.compile(r"^(kernel32|msvcrt|ucrtbase|advapi32|user32|ntdll|api-ms-win-[a-z0-9-]+)\.dll$", re.I)


def record_line(name: str, data: bytes) -> str:
    digest = base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
    return f"{name},sha256={digest},{len(data)}"


def assemble(pure_wheel: str, core_pyd: str, openblas_dll: str, dist: str) -> Path:
    with zipfile.ZipFile(pure_wheel) as source:
        files = {name: source.read(name) for name in source.namelist()}
    dist_info = next(name.split("/")[0] for name in files if name.endswith(".dist-info/WHEEL"))
    if any(name.startswith("skinkit/_core.") and not name.endswith(".pyi") for name in files):
        raise SystemExit(f"{pure_wheel}: already holds an extension (build it with SKINKIT_WITHOUT_EXTENSION=1)")
    files["skinkit/_core.pyd"] = Path(core_pyd).read_bytes()
    files[f"skinkit/{Path(openblas_dll).name}"] = Path(openblas_dll).read_bytes()
    wheel_text = files[f"{dist_info}/WHEEL"].decode()
    wheel_text = re.sub(r"^Root-Is-Purelib: .*$", "Root-Is-Purelib: false", wheel_text, flags=re.M)
    wheel_text = re.sub(r"^Tag: .*\n", "", wheel_text, flags=re.M).rstrip("\n") + f"\nTag: {TAG}\n"
    files[f"{dist_info}/WHEEL"] = wheel_text.encode()
    record = f"{dist_info}/RECORD"
    files.pop(record, None)
    lines = [record_line(name, data) for name, data in sorted(files.items())] + [f"{record},,"]
    files[record] = ("\n".join(lines) + "\n").encode()
    name, version = dist_info[:-len(".dist-info")].split("-")
    out = Path(dist) / f"{name}-{version}-{TAG}.whl"
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.NamedTemporaryFile(dir=out.parent, suffix=".part", delete=False) as partial:
        with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as wheel:
            for member in sorted(files, key=lambda n: (n.startswith(dist_info), n)):  # dist-info last, as pip does
                wheel.writestr(member, files[member])
    os.replace(partial.name, out)
    return out


def pe_table(path: Path) -> tuple[list[str], list[str]]:
    """(exported names, imported DLL names) of a PE file, from objdump -p."""
    text = subprocess.run([OBJDUMP, "-p", str(path)], check=True, capture_output=True, text=True).stdout
    imports = re.findall(r"^\s*DLL Name: (\S+)$", text, flags=re.M)
    exports = []
    table = text.split("[Ordinal/Name Pointer] Table", 1)
    if len(table) == 2:
        for line in table[1].splitlines()[1:]:
            found = re.match(r"^\s*\[\s*\d+\]\s+(\S+)$", line)
            if not found:
                break
            exports.append(found[1])
    return exports, imports


def check(wheel_path: str) -> list[str]:
    problems = []
    with zipfile.ZipFile(wheel_path) as wheel, tempfile.TemporaryDirectory() as scratch:
        names = wheel.namelist()
        if f"Tag: {TAG}" not in wheel.read(next(n for n in names if n.endswith(".dist-info/WHEEL"))).decode():
            problems.append(f"WHEEL does not say Tag: {TAG}")
        if "skinkit/_core.pyd" not in names:
            return problems + ["no skinkit/_core.pyd"]
        wheel.extractall(scratch, [n for n in names if n.endswith((".pyd", ".dll"))])
        bundled = {Path(n).name.lower() for n in names if n.startswith("skinkit/") and n.endswith(".dll")}
        exports, imports = pe_table(Path(scratch, "skinkit", "_core.pyd"))
        if exports != ["PyInit__core"]:
            problems.append(f"_core.pyd exports {exports}, not exactly PyInit__core")
        if "python3.dll" not in [i.lower() for i in imports]:
            problems.append(f"_core.pyd does not import python3.dll (imports {imports})")
        for dll in imports:
            if dll.lower() != "python3.dll" and dll.lower() not in bundled and not SYSTEM_DLL.match(dll):
                problems.append(f"_core.pyd imports {dll}: neither python3.dll, bundled, nor a system DLL")
        for dll in sorted(bundled):
            for inner in pe_table(Path(scratch, "skinkit", dll))[1]:
                if not SYSTEM_DLL.match(inner) and inner.lower() not in bundled:
                    problems.append(f"{dll} imports {inner}, which is not a system DLL")
        print(f"{wheel_path}: _core.pyd exports {exports}; imports {imports}; bundled {sorted(bundled)}")
    return problems


def through_pipe(command: list[str]) -> int:
    with subprocess.Popen(["env", *command], stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT) as child:
        for line in child.stdout:
            sys.stdout.buffer.write(line)
            sys.stdout.flush()
    return child.returncode


def main(argv: list[str]) -> None:
    if len(argv) == 5 and argv[0] == "assemble":
        print(assemble(*argv[1:]))
    elif len(argv) == 2 and argv[0] == "check":
        problems = check(argv[1])
        if problems:
            raise SystemExit("\n".join(f"{argv[1]}: {p}" for p in problems))
    elif len(argv) >= 2 and argv[0] == "through-pipe":
        sys.exit(through_pipe(argv[1:]))
    else:
        raise SystemExit(__doc__)


if __name__ == "__main__":
    main(sys.argv[1:])
