#!/usr/bin/env python3
"""The crates tests/run.sh's no-default step compiles again, as cargo --config arguments that
compile them unoptimised.

`cargo test --no-default-features --test it` reuses what the all-features test build compiled,
except the crates whose features differ without the optional backends (the OPC UA stack, rawler,
CharLS switch features on in tokio, rustls, the DICOM stack, ...) and every crate above them:
about 45 crates, 2.3 minutes of compiling at the test profile's opt-level 2 on 2 cores, for four
tests that run in a fraction of a second. This script finds them with `cargo tree` (the resolved
features of every target-side crate, with and without the optional features; a crate is compiled
again when its features differ or when anything it depends on is compiled again) and prints one
`--config` and one `profile.dev.package."NAME@VERSION".opt-level=0` line per crate, layerwise included
(with 16 codegen units for it). A
crate named that is not compiled again would be, unoptimised: slower, never wrong. On any error
it prints nothing, and the step compiles them as before.

Usage: python3 tests/no_default_rebuilds.py   (from the crate root)
"""
import re
import subprocess
import sys


def tree(args):
    """{"name vX.Y.Z|features": {children}} of the target-side graph (no build scripts, no proc
    macros: those run on the host and are unoptimised in every build)."""
    out = subprocess.run(
        ["cargo", "tree", "--locked", "--prefix", "depth", "-f", "{p}|{f}",
         "-e", "normal,dev,no-proc-macro", *args],
        capture_output=True, text=True, check=True,
    ).stdout
    nodes, stack = {}, []
    for line in out.splitlines():
        m = re.match(r"(\d+)(.*)", line)
        if not m:
            continue
        depth = int(m.group(1))
        node = re.sub(r" \([^)]*\)", "", m.group(2)).strip()
        stack[depth:] = [node]
        nodes.setdefault(node, set())
        if depth:
            nodes[stack[depth - 1]].add(node)
    return nodes


def main():
    built = tree(["--workspace", "--all-features"])
    wanted = tree(["-p", "layerwise", "--no-default-features"])
    memo = {}

    def again(node):
        if node not in memo:
            memo[node] = False
            memo[node] = node not in built or any(again(c) for c in wanted[node])
        return memo[node]

    # "name@version": a name alone would take every version of a crate (getrandom 0.2 differs,
    # 0.3 and 0.4 do not, and would compile again with everything above them).
    specs = sorted({n.split("|")[0].replace(" v", "@") for n in wanted if again(n)})
    for spec in specs:
        name = spec.split("@")[0]
        if name == "mock_camera":
            continue
        if name == "layerwise":
            # Cargo.toml sets it by name; a second spec for it is refused.
            spec = name
            # Cargo.toml's one codegen unit saves CPU at opt-level 1, where the lib and its
            # tests compile side by side; unoptimised, alone, it only serialises the compiling
            # (this step 125 s instead of 57 on 2 cores).
            print("--config")
            print(f'profile.dev.package."{spec}".codegen-units=16')
        print("--config")
        print(f'profile.dev.package."{spec}".opt-level=0')


if __name__ == "__main__":
    try:
        main()
    except Exception as e:  # the step then compiles them as before, only slower
        print(f"no_default_rebuilds.py: {e}", file=sys.stderr)
