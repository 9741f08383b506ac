"""Generates the CPython binding of the C core from scripts/binding_spec.py (`make bindings`):

  csrc/binding/pymodule.c  the stable-ABI module skinkit._core: per function one DEFINE_ENTRY (its docstring, its
                           argument table as text and its C call), on the shared runtime csrc/binding/runtime.h
  skinkit/_core.pyi        type stubs with the docstrings

    python scripts/gen_bindings.py [--out DIR] [--spec PATH]

--out writes both files under DIR (same relative paths) instead of the repository; tests/test_binding.py uses it to
check that the checked-in files are current.
"""
from __future__ import annotations

import argparse
import importlib.util
import os
import re
import sys
import textwrap
from dataclasses import dataclass

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
SPEC = os.path.join(ROOT, "scripts", "binding_spec.py")
C_OUTPUT = os.path.join("csrc", "binding", "pymodule.c")
STUB_OUTPUT = os.path.join("skinkit", "_core.pyi")
WIDTH = 118
DOC_WIDTH = 100
MAX_FACTORS = 3  # csrc/binding/runtime.h: the known counts a size may multiply
TABLE_HEADING = "name, kind, types, size, step, derived count"

DTYPE_NAMES = {"d": "float64", "f": "float32", "df": "float64 or float32", "i": "int32", "B": "uint8 or bool",
               "H": "uint16"}
KIND_NAMES = {"size": "SIZE", "real": "REAL", "integer": "INTEGER", "flag": "FLAG", "progress": "PROGRESS"}
PYTHON_TYPES = {"size": "int", "real": "float", "integer": "int", "flag": "bool",
                "progress": "Callable[[float], object] | None"}
FIELD_TYPES = {"n": "int", "i": "int", "d": "float"}
PLACEHOLDER = re.compile(r"\{(\w+)\}")


def load_spec(path: str):
    spec = importlib.util.spec_from_file_location("binding_spec", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


# ---- sizes -------------------------------------------------------------------------------------------------------

@dataclass(frozen=True)
class Size:
    """An array length as factor * counts... + bias, parsed from "16*example_count*bone_count" or "vertex_count+1"."""
    factor: int
    counts: tuple[str, ...]
    bias: int
    text: str

    @classmethod
    def parse(cls, text: str) -> "Size":
        product, _, bias = text.partition("+")
        factor, counts = 1, []
        for term in product.split("*"):
            if term.isdigit():
                factor *= int(term)
            else:
                counts.append(term)
        return cls(factor, tuple(counts), int(bias or 0), text)


@dataclass(frozen=True)
class Rule:
    argument: int
    size: Size
    derives: str | None  # the count it sets, or None to check the length


def size_rules(function) -> list[Rule]:
    """Derivations first (each count from the first array that has it as its only unknown, inputs before in/out
    arrays before destinations), then a check of every other array."""
    arrays = [(i, a, Size.parse(a.size)) for i, a in enumerate(function.arguments) if hasattr(a, "types")]
    known = {a.name for a in function.arguments if getattr(a, "kind", None) == "size"}
    rules, derived = [], set()
    while True:
        rule = next_derivation(arrays, known, derived)
        if rule is None:
            break
        rules.append(rule)
        derived.add(rule.argument)
        known.add(rule.derives)
    for i, a, size in arrays:
        if i not in derived:
            unknown = set(size.counts) - known
            if unknown:
                raise ValueError(f"{function.name}: {a.name}'s size {size.text} has unknown counts {sorted(unknown)}")
            rules.append(Rule(i, size, None))
    for rule in rules:
        if len([c for c in rule.size.counts if c != rule.derives]) > MAX_FACTORS:
            raise ValueError(f"{function.name}: {rule.size.text} multiplies more than {MAX_FACTORS} known counts")
    return rules


def next_derivation(arrays, known, derived) -> Rule | None:
    for role in ("in", "inout", "out"):
        for i, a, size in arrays:
            unknown = [c for c in size.counts if c not in known]
            if a.role == role and not a.optional and i not in derived and len(unknown) == 1:
                return Rule(i, size, unknown[0])
    return None


def count_names(functions) -> list[str]:
    names = set()
    for function in functions:
        for a in function.arguments:
            if hasattr(a, "types"):
                names.update(Size.parse(a.size).counts)
            elif a.kind == "size":
                names.add(a.name)
    return sorted(names)


def count_constant(name: str) -> str:
    return "N_" + name.upper()


# ---- C ---------------------------------------------------------------------------------------------------------

def c_string(text: str) -> str:
    escaped = text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")
    return f'"{escaped}"'


def c_text_block(lines: list[str], indent: str = "    ", separator: str = "") -> str:
    """A C string literal of several lines, one literal per line (or, with a separator, one string per line)."""
    if separator:
        return "".join(f"{indent}{c_string(line)}{separator}\n" for line in lines)
    return "\n".join(indent + c_string(line + "\n") for line in lines[:-1]) + "\n" + indent + c_string(lines[-1])


def wrap(line: str, width: int = WIDTH) -> str:
    """Breaks a C statement after commas, continuing under the character after its first "(" (or its indent)."""
    position = line.find("(")
    indent = position + 1 if position >= 0 else len(line) - len(line.lstrip())
    lines, current = [], ""
    for piece in re.split(r"(?<=,) ", line):
        if current and len(current) + 1 + len(piece) > width:
            lines.append(current)
            current = " " * indent + piece
        else:
            current = f"{current} {piece}" if current else piece
    lines.append(current)
    return "\n".join(lines)


def argument_row(argument, step: int, rule: Rule | None) -> list[str]:
    """The columns of the argument's line in the entry's table (csrc/binding/runtime.h: read_table)."""
    if hasattr(argument, "types"):
        role = "optional_" * argument.optional + argument.role
        return [argument.name, role, argument.types, argument.size, str(step)] + [rule.derives] * bool(rule.derives)
    bounds = {"size": [str(argument.minimum)], "integer": [str(argument.minimum), str(argument.maximum)]}
    return [argument.name, argument.kind] + bounds.get(argument.kind, [])


def argument_table(function) -> list[str]:
    """One line per argument, in aligned columns."""
    steps = {rule.argument: (step, rule) for step, rule in enumerate(size_rules(function))}
    rows = [argument_row(a, *steps.get(i, (-1, None))) for i, a in enumerate(function.arguments)]
    widths = [max(len(row[c]) for row in rows if len(row) > c) for c in range(max(map(len, rows)))]
    return ["  ".join(cell.ljust(width) for cell, width in zip(row, widths)).rstrip() for row in rows]


def placeholders(function) -> dict[str, str]:
    """The C expression each {name} of the call template stands for."""
    values = {"error": "error"}
    for i, a in enumerate(function.arguments):
        kind = "array" if hasattr(a, "types") else a.kind
        values[a.name] = {"array": f"f->data[{i}]", "real": f"f->real[{i}]", "integer": f"f->integer[{i}]",
                          "flag": f"f->integer[{i}]", "progress": "report_progress, f->progress"}.get(kind, "")
    for a in function.arguments:
        for count in (Size.parse(a.size).counts if hasattr(a, "types") else [a.name] * (a.kind == "size")):
            values[count] = f"f->count[{count_constant(count)}]"
    for group in function.groups:
        members = ", ".join(f"{{{f}}}" for f in group.fields)
        values[group.name] = f"&(const {group.c_type}){{{members}}}" if group.as_struct else members
    if function.result:
        values[function.result.name] = f"&f->result.{function.result.member}"
    return values


def expand(template: str, values: dict[str, str], function_name: str) -> str:
    def substitute(match):
        name = match.group(1)
        if name not in values:
            raise ValueError(f"{function_name}: the call names {{{name}}}, which is not an argument, count or group")
        return PLACEHOLDER.sub(substitute, values[name])
    return PLACEHOLDER.sub(substitute, template)


def check_call(function) -> None:
    """Names match C 1:1 (the C name without sk_ and _f64/_f32), and the call passes every argument."""
    called = re.match(r"(\w+?)(_\{precision\})?\(", function.call).group(1)
    if not function.test_helper and called != "sk_" + function.name:
        raise ValueError(f"{function.name}: calls {called}; the Python name must be the C name without sk_")
    used = set(PLACEHOLDER.findall(function.call))
    for group in function.groups:
        if group.name in used:
            used.update(group.fields)
    missing = [a.name for a in function.arguments if a.name not in used]
    if missing:
        raise ValueError(f"{function.name}: the call does not pass {missing}")


def c_call(function) -> str:
    """The C call on the frame's arguments (f->data[i], f->count[N_...], ...), _f32 or _f64 by the precision."""
    check_call(function)
    call = lambda precision: expand(function.call.replace("{precision}", precision), placeholders(function),
                                    function.name)
    if "{precision}" in function.call:
        return f"f->single_precision ? {call('f32')} : {call('f64')}"
    return call("f64")


def describe(argument) -> str:
    if hasattr(argument, "types"):
        role = {"in": "", "out": ", written", "inout": ", read and written"}[argument.role]
        return f"{argument.name}: {DTYPE_NAMES[argument.types]}[{argument.size}]{role}" + " or None" * argument.optional
    if argument.maximum:
        bounds = f" in [{argument.minimum}, {argument.maximum}]"
    else:
        bounds = f" >= {argument.minimum}" if argument.minimum else ""
    return f"{argument.name}: {PYTHON_TYPES[argument.kind]}{bounds}"


def returns(function) -> str:
    if not function.result:
        return "Returns None."
    return "Returns a dict: " + ", ".join(name for name, _ in function.result.fields) + "."


def pack(items: list[str], width: int, indent: str = "") -> list[str]:
    """The items, a space between them, as many a line as fit in width (later lines start with indent); no item
    is broken, so a type such as Callable[[float], object] stays whole."""
    lines = [items[0]]
    for item in items[1:]:
        if len(lines[-1]) + 1 + len(item) > width:
            lines.append(indent + item)
        else:
            lines[-1] += " " + item
    return lines


def punctuated(items: list[str], separator: str, end: str) -> list[str]:
    """Each item but the last followed by separator, the last by end."""
    return [item + separator for item in items[:-1]] + [items[-1] + end]


def doc_lines(function) -> list[str]:
    return textwrap.wrap(function.doc, DOC_WIDTH) + [""] + [describe(a) for a in function.arguments] + \
        ["", returns(function)]


def function_block(function) -> str:
    """DEFINE_ENTRY(name, result dict, docstring, argument table, C call): one line of code, the call, unwrapped."""
    text_signature = function.name + "($module, " + ", ".join(a.name for a in function.arguments) + ")"
    result = f"{function.result.member}_dict" if function.result else "NULL"
    return (f"DEFINE_ENTRY({function.name}, {result},\n" +
            c_text_block([text_signature, "--", ""] + doc_lines(function)) + ",\n" +
            c_text_block([f"# {function.name}: {TABLE_HEADING}"] + argument_table(function)) + ",\n" +
            f"    {c_call(function)})\n")


def distinct_results(functions):
    results = {}
    for function in functions:
        if function.result:
            results.setdefault(function.result.member, function.result)
    return list(results.values())


def result_dict(result) -> str:
    """Py_BuildValue of the result's fields, as a dict."""
    scalar = not result.c_type.startswith("sk_")
    value = (lambda name: "*r") if scalar else (lambda name: f"r->{name}")
    cast = {"n": "(Py_ssize_t)", "i": "", "d": ""}
    format_ = "{" + ",".join(f"s:{code}" for _, code in result.fields) + "}"
    values = ", ".join(f'"{name}", {cast[code]}{value(name)}' for name, code in result.fields)
    return (f"static PyObject *{result.member}_dict(const frame *f)\n{{\n"
            f"    const {result.c_type} *r = &f->result.{result.member};\n"
            + wrap(f"    return Py_BuildValue({c_string(format_)}, {values});") + "\n}\n")


def c_prelude(functions, spec_name: str) -> str:
    counts = ["NO_COUNT"] + [count_constant(c) for c in count_names(functions)] + ["COUNT_NAMES"]
    names = [""] + count_names(functions)
    results = distinct_results(functions)
    members = "".join(f"    {r.c_type} {r.member};\n" for r in results) or "    char none;\n"
    return (f"/*\n * skinkit._core: generated by scripts/gen_bindings.py from {spec_name}; do not edit.\n"
            " * Regenerate with `make bindings`; tests/test_binding.py checks that this file is current.\n *\n"
            " * The CPython binding of the C core, built against the stable ABI (Py_LIMITED_API 3.11) so that one\n"
            " * binary loads in every Blender from 4.2 on. Arrays cross through the buffer protocol (no numpy C API);\n"
            " * the Python layer (the modules in skinkit/) allocates destinations and checks shapes, and this layer\n"
            " * re-checks element types and counts (overflow-checked) so that no call can read or write out of\n"
            " * bounds. Every C call runs with the GIL released.\n */\n"
            "#define PY_SSIZE_T_CLEAN\n#include <Python.h>\n\n#include <ctype.h>\n#include <limits.h>\n"
            "#include <stdint.h>\n#include <stdio.h>\n#include <stdlib.h>\n#include <string.h>\n\n"
            "#include \"skinkit.h\"\n\n"
            "/* Every count an array size can name. */\n"
            "typedef enum count_name {\n" + wrap("    " + ", ".join(counts)) + "\n} count_name;\n"
            "static const char *const count_names[] = {\n" + c_text_block(names, separator=",") + "};\n\n"
            "/* What the C calls write besides arrays: the reports and scalar results. */\n"
            "typedef union result_storage {\n" + members + "} result_storage;\n\n"
            "#include \"runtime.h\"\n")


def c_module(functions, spec_name: str) -> str:
    parts = [c_prelude(functions, spec_name)]
    parts += ["\n/* ---- results ---- */\n"] + [result_dict(r) for r in distinct_results(functions)]
    parts += [function_block(f) for f in functions]
    entries = ", ".join(f"&{f.name}_entry" for f in functions)
    parts.append("/* ---- the module ---- */\n\n"
                 "static entry *const entries[] = {\n" + wrap("    " + entries) + "};\n"
                 "static PyMethodDef definitions[LENGTH(entries)];\n\n"
                 "PyMODINIT_FUNC PyInit__core(void)\n{\n"
                 "    return create_module(entries, LENGTH(entries), definitions);\n}\n")
    return "\n".join(parts)


# ---- type stubs ------------------------------------------------------------------------------------------------

def typed_dict_name(result) -> str:
    words = result.member.split("_")
    return "".join(w.capitalize() for w in words) + ("" if result.c_type.startswith("sk_") else "Result")


def python_type(argument) -> str:
    if hasattr(argument, "types"):
        return "np.ndarray | None" if argument.optional else "np.ndarray"
    return PYTHON_TYPES[argument.kind]


def stub_function(function) -> str:
    """The signature on one line (wrapped only when longer than WIDTH), then the docstring: what the function
    does, the parameters' dtypes and lengths as one paragraph (one a line would repeat the same runs of lines
    from stub to stub), and what it returns."""
    result = typed_dict_name(function.result) if function.result else "None"
    head = f"def {function.name}("
    parameters = punctuated([f"{a.name}: {python_type(a)}" for a in function.arguments], ",", f") -> {result}:")
    signature = pack([head + parameters[0]] + parameters[1:], WIDTH, " " * len(head))
    doc = textwrap.wrap(function.doc, DOC_WIDTH) + [""] + \
        pack(punctuated([describe(a) for a in function.arguments], ";", "."), DOC_WIDTH) + \
        [""] + textwrap.wrap(returns(function), DOC_WIDTH)
    return "\n".join(signature) + '\n    """' + "\n    ".join(doc).replace("\n    \n", "\n\n") + '\n    """\n'


def stub_module(functions, spec_name: str) -> str:
    parts = [f'"""Type stubs of skinkit._core, generated by scripts/gen_bindings.py from {spec_name}; do not edit.\n\n'
             "Arrays are C-contiguous numpy arrays (any buffer works); the docstrings give each one's dtype and\n"
             'length. Errors: Error (a ValueError) for a failed call, TypeError/ValueError naming the argument."""\n'
             "from typing import Callable, TypedDict\n\nimport numpy as np\n\ncore_version: str\n\n\n"
             "class Error(ValueError): ...\n"]
    for result in distinct_results(functions):
        fields = "".join(f"    {name}: {FIELD_TYPES[code]}\n" for name, code in result.fields)
        parts.append(f"\nclass {typed_dict_name(result)}(TypedDict):\n{fields}")
    parts += ["\n" + stub_function(f) for f in functions]
    return "\n".join(parts)


# ---- main ------------------------------------------------------------------------------------------------------

def generate(out_root: str, spec_path: str = SPEC) -> list[str]:
    spec = load_spec(spec_path)
    spec_name = os.path.relpath(spec_path, ROOT) if spec_path.startswith(ROOT) else os.path.basename(spec_path)
    spec_name = spec_name.replace(os.sep, "/")  # the generated files name it the same on every platform
    written = []
    for relative, text in ((C_OUTPUT, c_module(spec.FUNCTIONS, spec_name)),
                           (STUB_OUTPUT, stub_module(spec.FUNCTIONS, spec_name))):
        path = os.path.join(out_root, relative)
        os.makedirs(os.path.dirname(path), exist_ok=True)
        with open(path, "w") as file:
            file.write(text)
        written.append(path)
    return written


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=ROOT, help="root to write csrc/binding/pymodule.c and skinkit/_core.pyi under")
    parser.add_argument("--spec", default=SPEC, help="the spec module (default scripts/binding_spec.py)")
    args = parser.parse_args(argv)
    for path in generate(args.out, args.spec):
        print(f"wrote {os.path.relpath(path)}")


if __name__ == "__main__":
    main()
