#!/usr/bin/env python3
"""Where the training configuration travels from `train_distributed`, read as text.

usage: lab/house/cfg_walk.py [ROOT] [--parts] [--start NAME] [--trace]
  ROOT     the repository (default: the current directory)
  --parts  follow the configuration's parts too (below); issue 61's measure
  --start  the function the walk starts from (default: train_distributed)
  --trace  print every step of the walk (each file entered, and each return)

The walk follows the configuration the way a reader following `cfg` reads the code. It starts
in the function named by --start in crates/rtf-train/src, whose parameters typed `&TrainConfig`
or `&RunConfig` (with or without a lifetime) are the *tracked variables* (`self` in a `&self`
method of `impl TrainConfig` / `impl RunConfig`). Inside a function the walk goes, in source
order, into every call of a function of crates/rtf-train/src that passes a tracked variable:

- whole (default): as an argument (`f(cfg)`, `f(&cfg, ..)`, `T::of(cfg)`) or as the receiver
  (`cfg.validate()`); in the callee its parameters typed as the whole configuration are
  tracked.
- `--parts`: also a field path of it (`f(&cfg.data)`, `cfg.data.dataset.choice()`); in the
  callee the parameters that received one are tracked (whatever their type), so the walk
  follows a section as far as it is passed on. A method on a field path is resolved by its
  name when one method of the crate has it.

A value stored in a struct and read back later is not followed (the walk reads calls, not
fields). Each function is read once (a second call to it is not walked again); calls of
functions outside crates/rtf-train/src (other crates, re-exports) are not followed. After a
callee the walk comes back to the caller's file.

The count: every time the walk moves into a file it has been in before (back to the caller's
file after a call into another file, or a call into a file read earlier) is one *return to a
file already left*. The report gives the functions walked, the returns per file and the
total. Comments, string literals and `#[cfg(test)]` modules are left out.

Measured (issue 61): before the run plan, 29 returns with --parts (trainer.rs 9), 8 whole;
with the run plan, 10 with --parts, 2 whole. With the schema moved to rtf-config (10c9848 →
its successor), 3 with --parts, 1 whole: of the 7 fewer, the 3 returns into
`config/mod.rs` went with its methods (`DatasetConfig::choice`/`recorded`, `validate`),
which the walk, reading rtf-train only, no longer enters.
"""
import os
import re
import sys
from collections import Counter

CONFIG_TYPES = ("TrainConfig", "RunConfig")


def strip(src):
    """Comments and string/char literals blanked, newlines kept."""
    out, i, n = [], 0, len(src)
    while i < n:
        c = src[i]
        if src.startswith("//", i):
            j = src.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif src.startswith("/*", i):
            j = src.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append(re.sub(r"[^\n]", " ", src[i:j]))
            i = j
        elif c == "r" and re.match(r'r#*"', src[i:i + 10]) and (
                i == 0 or not (src[i - 1].isalnum() or src[i - 1] == "_")):
            hashes = re.match(r'r(#*)"', src[i:]).group(1)
            end = '"' + hashes
            j = src.find(end, i + len(hashes) + 2)
            j = n if j < 0 else j + len(end)
            out.append(re.sub(r"[^\n]", " ", src[i:j]))
            i = j
        elif c == '"':
            j = i + 1
            while j < n and src[j] != '"':
                j += 2 if src[j] == "\\" else 1
            out.append(re.sub(r"[^\n]", " ", src[i:j + 1]))
            i = j + 1
        elif c == "'" and re.match(r"'(\\.|[^\\'])'", src[i:i + 4]):
            m = re.match(r"'(\\.|[^\\'])'", src[i:])
            out.append(" " * len(m.group(0)))
            i += len(m.group(0))
        else:
            out.append(c)
            i += 1
    return "".join(out)


def block_end(s, j):
    """The index after the block whose `{` is at j."""
    depth = 0
    while j < len(s):
        depth += {"{": 1, "}": -1}.get(s[j], 0)
        j += 1
        if depth == 0:
            return j
    return j


def test_spans(s):
    pattern = r"#\[cfg\(test\)\]\s*(pub(\([^)]*\))?\s+)?mod\s+\w+\s*\{"
    return [(m.start(), block_end(s, m.end() - 1)) for m in re.finditer(pattern, s)]


def impl_spans(s):
    """(start, end, type) of every `impl ... Type ... {` block."""
    spans = []
    for m in re.finditer(r"\bimpl\b(<[^{]*?>)?\s+([^{;]*?)\{", s):
        header = m.group(2)
        target = header.split(" for ")[-1].strip()
        name = re.match(r"[\w:]*?(\w+)\s*(<.*)?$", target)
        spans.append((m.start(), block_end(s, m.end() - 1), name.group(1) if name else target))
    return spans


class Function:
    def __init__(self, path, name, line, impl, params, body):
        self.path, self.name, self.line, self.impl = path, name, line, impl
        self.body = body
        self.params = parse_params(params, impl)

    def config_vars(self):
        """The parameters typed as the whole configuration (`self` in its impls)."""
        return {n: t for n, t in self.params if t in CONFIG_TYPES}

    def __repr__(self):
        owner = f"{self.impl}::" if self.impl else ""
        return f"{owner}{self.name} ({self.path}:{self.line})"


def split_top(text, sep=","):
    parts, depth, cur = [], 0, []
    for i, ch in enumerate(text):
        if ch in "([{" or (ch == "<" and i and text[i - 1] != "-"):
            depth += 1
        elif ch in ")]}" or (ch == ">" and i and text[i - 1] not in "-="):
            depth -= 1
        if ch == sep and depth == 0:
            parts.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    if "".join(cur).strip():
        parts.append("".join(cur))
    return parts


def parse_params(params, impl):
    """(name, type) of each parameter: the type's last path segment without `&`, `mut` and
    lifetimes (`self`: the impl's type)."""
    out = []
    for p in split_top(params):
        p = p.strip()
        if re.fullmatch(r"&?\s*('\w+\s+)?(mut\s+)?self", p):
            out.append(("self", impl))
            continue
        m = re.fullmatch(r"(mut\s+)?(\w+)\s*:\s*(.*)", p, re.S)
        if not m:
            out.append(("_", None))
            continue
        ty = re.sub(r"&|'\w+|\bmut\b|\bdyn\b", "", m.group(3)).strip()
        ty = re.match(r"([\w:]*)", ty).group(1).split("::")[-1]
        out.append((m.group(2), ty))
    return out


def functions(root, path):
    s = strip(open(os.path.join(root, path), encoding="utf-8").read())
    tests, impls = test_spans(s), impl_spans(s)
    for m in re.finditer(r"\bfn\s+(\w+)\s*(<[^{;(]*?>)?\s*\(", s):
        if any(a <= m.start() < b for a, b in tests):
            continue
        close = m.end()
        depth = 1
        while close < len(s) and depth:
            depth += {"(": 1, ")": -1}.get(s[close], 0)
            close += 1
        j = close
        while j < len(s) and s[j] not in "{;":
            j += 1
        if j >= len(s) or s[j] == ";":
            continue
        impl = next((t for a, b, t in impls if a <= m.start() < b), None)
        body = s[j:block_end(s, j)]
        line = s.count("\n", 0, m.start()) + 1
        yield Function(path, m.group(1), line, impl, s[m.end():close - 1], body)


KEYWORDS = {"if", "while", "match", "for", "return", "Some", "Ok", "Err", "fn", "Box", "Arc",
            "vec", "format", "matches", "assert", "println", "eprintln"}


def passes(arg, tracked, parts):
    """The tracked variable `arg` passes (whole, or with --parts a field path of it)."""
    for var in tracked:
        if re.fullmatch(rf"[&*]?\s*{var}", arg):
            return var
        if parts and re.fullmatch(rf"[&*]?\s*{var}(\.\w+)+", arg):
            return var
    return None


def calls(fn, tracked, parts):
    """(position, qualifier, name, receiver type or None, argument indices passing a tracked
    variable) of each call in fn's body that passes one, in source order."""
    found = []
    for var, ty in tracked.items():
        # The receiver: `cfg.method(`; with --parts also `cfg.field.method(`.
        chain = r"(\.\w+)*?" if parts else ""
        for m in re.finditer(rf"(?<![\w.]){var}{chain}\s*\.\s*(\w+)\s*(::<[^>]*>)?\(", fn.body):
            whole = m.group(1) is None if parts else True
            found.append((m.start(), "", m.group(2 if parts else 1), ty if whole else "?", [0]))
    for m in re.finditer(r"((?:\w+::)*)(\w+)\s*(::<[^>]*>)?\(", fn.body):
        if m.group(2) in KEYWORDS or (m.start() > 0 and fn.body[m.start() - 1] == "."):
            continue
        depth, j = 1, m.end()
        while j < len(fn.body) and depth:
            depth += {"(": 1, ")": -1}.get(fn.body[j], 0)
            j += 1
        args = [a.strip() for a in split_top(fn.body[m.end():j - 1])]
        hits = [i for i, a in enumerate(args) if passes(a, tracked, parts)]
        if hits:
            found.append((m.start(), m.group(1).rstrip(":"), m.group(2), None, hits))
    found.sort(key=lambda c: c[0])
    return found


def module_of(path):
    parts = path[:-3].split("/")
    return parts[-2] if parts[-1] == "mod" else parts[-1]


def resolve(qualifier, name, receiver, caller, fns):
    candidates = [f for f in fns if f.name == name]
    if receiver is not None:
        candidates = [f for f in candidates if f.params[:1] and f.params[0][0] == "self"]
        if receiver != "?":
            candidates = [f for f in candidates if f.impl == receiver]
        elif len(candidates) != 1:
            return None
    last = qualifier.split("::")[-1] if qualifier else ""
    if last and last[0].isupper():
        impl = caller.impl if last == "Self" else last
        candidates = [f for f in candidates if f.impl == impl]
    elif last and last not in ("crate", "super", "self"):
        candidates = [f for f in candidates if module_of(f.path) == last and not f.impl]
    elif receiver is None:
        candidates = [f for f in candidates if not f.params[:1] or f.params[0][0] != "self"]
    same_file = [f for f in candidates if f.path == caller.path]
    return (same_file or candidates or [None])[0]


class Walk:
    def __init__(self, fns, parts, trace):
        self.fns, self.parts, self.trace = fns, parts, trace
        self.current, self.visited, self.walked = None, set(), []
        self.returns = Counter()

    def move(self, path, why):
        if path == self.current:
            return
        again = path in self.visited
        if again:
            self.returns[path] += 1
        if self.trace:
            print(f"  {'return ' if again else 'enter  '}{path}  ({why})")
        self.current = path
        self.visited.add(path)

    def tracked_in(self, callee, receiver, hits):
        if not self.parts:
            return callee.config_vars()
        offset = 0 if receiver is not None or callee.params[:1] == [] or callee.params[0][0] != "self" else 1
        names = {}
        for i in hits:
            if i + offset < len(callee.params):
                name, ty = callee.params[i + offset]
                names[name] = ty
        return names

    def walk(self, fn, tracked):
        self.walked.append(fn)
        self.move(fn.path, repr(fn))
        for _, qualifier, name, receiver, hits in calls(fn, tracked, self.parts):
            callee = resolve(qualifier, name, receiver, fn, self.fns)
            if callee is None or callee in self.walked:
                continue
            inner = self.tracked_in(callee, receiver, hits)
            if not inner:
                continue
            self.walk(callee, inner)
            self.move(fn.path, f"back in {fn.name}")


def main(argv):
    args = [a for a in argv if not a.startswith("--")]
    root = args[0] if args else "."
    start = argv[argv.index("--start") + 1] if "--start" in argv else "train_distributed"
    if "--start" in argv:
        args.remove(start)
        root = args[0] if args else "."
    src = "crates/rtf-train/src"
    fns = []
    for dp, _, files in os.walk(os.path.join(root, src)):
        for f in sorted(files):
            if f.endswith(".rs"):
                fns.extend(functions(root, os.path.relpath(os.path.join(dp, f), root)))
    first = next((f for f in fns if f.name == start), None)
    if first is None:
        sys.exit(f"cfg_walk: no function `{start}` in {src}")
    walk = Walk(fns, "--parts" in argv, "--trace" in argv)
    walk.walk(first, first.config_vars())
    print(f"functions taking the whole configuration, walked from {start}: {len(walk.walked)}")
    for fn in walk.walked:
        print(f"  {fn!r}")
    print("returns to files already left, per file:")
    for path, n in walk.returns.most_common():
        print(f"  {n:3}  {path}")
    print(f"returns to files already left: {sum(walk.returns.values())}")


if __name__ == "__main__":
    main(sys.argv[1:])
