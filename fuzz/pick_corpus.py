#!/usr/bin/env python3
"""Picks the small committed corpus of a fuzz target out of its full working corpus.

    BIN=fuzz/target/x86_64-unknown-linux-gnu/release/gltf_load
    $BIN -merge=1 -use_counters=0 -merge_control_file=/tmp/cf.txt /tmp/empty fuzz/work/gltf_load
    python3 fuzz/pick_corpus.py /tmp/cf.txt fuzz/corpus/gltf_load 100 1000000

libFuzzer's own merge (`cargo fuzz cmin`) keeps every input that adds a feature, smallest first: a few
thousand files for gltf_load. This is a greedy set cover over the features each input reaches (with
`-use_counters=0` a feature is a coverage edge): it takes the input adding the most edges not yet
covered (ties: the smaller), until MAX_FILES or MAX_BYTES, and prints how much it kept.
"""

import os
import shutil
import sys


def main():
    control, out, max_files, max_bytes = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    lines = open(control).read().split("\n")
    n = int(lines[0])
    files = lines[2:2 + n]
    features = {}
    for line in lines[2 + n:]:
        parts = line.split()
        # "FT <file index> <features...>" lists every feature of that input.
        if parts and parts[0] == "FT":
            features[int(parts[1])] = set(map(int, parts[2:]))
    size = {i: os.path.getsize(files[i]) for i in features}
    everything = set().union(*features.values())
    chosen, have, total = [], set(), 0
    while len(chosen) < max_files:
        fits = [i for i in features if i not in chosen and total + size[i] <= max_bytes]
        if not fits:
            break
        best = max(fits, key=lambda i: (len(features[i] - have), -size[i]))
        if not features[best] - have:
            break
        chosen.append(best)
        have |= features[best]
        total += size[best]
    print(f"picked {len(chosen)} of {n} files, {total} bytes, "
          f"covering {len(have)} of {len(everything)} features")
    os.makedirs(out, exist_ok=True)
    for i in chosen:
        shutil.copy(files[i], os.path.join(out, os.path.basename(files[i])))


if __name__ == "__main__":
    main()
