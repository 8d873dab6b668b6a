#!/usr/bin/env python3
"""Checks JSON-lines traces (`icars run ... --trace FILE`) against docs/trace.schema.json.

    scripts/check-trace.py [--schema docs/trace.schema.json] TRACE.jsonl...

Every line must be one JSON object that the schema accepts (docs/trace.md describes it). Prints
one line per file, `FILE: N records ok (kind N, ...)`, or one error per bad record,
`FILE:LINE: <what is wrong> (kind K)`, at most 20 per file. Exit code 0 when every record of
every file is valid, 1 when one is not, 2 when the schema or a file cannot be read or the
validator is missing. The validator is python3-jsonschema (scripts/install-deps.sh).
"""
import argparse
import collections
import json
import os
import sys

MAX_ERRORS_PER_FILE = 20


def describe(error):
    where = "/".join(str(p) for p in error.absolute_path)
    return f"{error.message}" + (f" at {where}" if where else "")


def check_file(path, validator, best_match):
    kinds = collections.Counter()
    errors = 0
    try:
        lines = open(path, encoding="utf-8").read().splitlines()
    except OSError as e:
        print(f"{path}: cannot read the trace: {e.strerror}", file=sys.stderr)
        return 2
    for number, line in enumerate(lines, start=1):
        if not line.strip():
            continue
        try:
            record = json.loads(line)
        except json.JSONDecodeError as e:
            problem, kind = f"not JSON: {e.msg} at column {e.colno}", "?"
        else:
            errors_found = list(validator.iter_errors(record))
            # A branch that failed leaves its keys "unevaluated": name what failed instead.
            specific = [e for e in errors_found if e.validator != "unevaluatedProperties"]
            error = best_match(specific or errors_found)
            if error is None:
                kinds[record["kind"]] += 1
                continue
            problem = describe(error)
            kind = record.get("kind", "?") if isinstance(record, dict) else "?"
        errors += 1
        if errors <= MAX_ERRORS_PER_FILE:
            print(f"{path}:{number}: {problem} (kind {kind})")
    if errors:
        print(f"{path}: {errors} invalid records, {sum(kinds.values())} valid")
        return 1
    counts = ", ".join(f"{kind} {n}" for kind, n in sorted(kinds.items()))
    print(f"{path}: {sum(kinds.values())} records ok ({counts})")
    return 0


def main():
    default_schema = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "docs", "trace.schema.json")
    parser = argparse.ArgumentParser(description="Checks icars JSON-lines traces against the trace's JSON Schema.")
    parser.add_argument("--schema", default=os.path.normpath(default_schema), help="the schema (default: %(default)s)")
    parser.add_argument("traces", nargs="+", help="JSON-lines trace files")
    args = parser.parse_args()
    try:
        import jsonschema
        from jsonschema.exceptions import best_match
    except ImportError:
        print("check-trace: the Python module jsonschema is missing: install python3-jsonschema "
              "(scripts/install-deps.sh)", file=sys.stderr)
        return 2
    try:
        with open(args.schema, encoding="utf-8") as f:
            schema = json.load(f)
        jsonschema.Draft202012Validator.check_schema(schema)
    except (OSError, json.JSONDecodeError, jsonschema.SchemaError) as e:
        print(f"check-trace: {args.schema}: not a usable JSON Schema: {e}", file=sys.stderr)
        return 2
    validator = jsonschema.Draft202012Validator(schema)
    status = 0
    for path in args.traces:
        status = max(status, check_file(path, validator, best_match))
    return status


if __name__ == "__main__":
    sys.exit(main())
