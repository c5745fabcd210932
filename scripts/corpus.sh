#!/usr/bin/env bash
# corpus.sh — run kausal over the public netlist corpus and summarize the result (issue 22).
#
# For every netlist of the manifest (run from the netlist's own directory, so includes resolve):
#   1. `ngspice -b -r RAW FILE` (60 s at most): a netlist ngspice does not run (non-zero exit,
#      timeout, or a `.tran` card but no transient data) is left out of the counts; one without
#      a `.tran` card is counted apart ("no transient analysis");
#   2. `kausal check FILE`: a refusal is grouped by its first error (code and message shape,
#      the element kind for unsupported elements);
#   3. accepted netlists: `kausal sim -o CSV FILE` once (wall time against step 1's ngspice
#      run) and `kausal validate --format json FILE` (120 s at most): pass, fail (worst signal
#      and its normalized error) or no verdict (the error validate reported).
# Writes target/corpus/results.tsv (one row per netlist), target/corpus/summary.md, logs under
# target/corpus/logs/ and one JSON record per netlist under target/corpus/entries/; with
# --write, replaces the generated section of VALIDATION.md (its explanation column is kept).
#
# Usage: scripts/corpus.sh [--write] [--summary-only] [--resume] [--accepted] [--only TEXT] [--list FILE]
#                          [--jobs N] [CORPUS_DIR [MANIFEST [KAUSAL_BIN]]]
#   CORPUS_DIR  default $KAUSAL_CORPUS, else ../corpus next to the repository root
#               (laid out by scripts/corpus-fetch.sh: CORPUS_DIR/<owner>+<name>/<path>)
#   MANIFEST    default $KAUSAL_MANIFEST, else ../shared/corpus/MANIFEST.tsv
#   KAUSAL_BIN  default $KAUSAL_BIN, else $CARGO_TARGET_DIR/release/kausal or target/release/kausal
#               (built with `cargo build --release` when missing)
#   --summary-only  rebuild results.tsv and the summary from target/corpus/entries/ without running
#   --resume        keep the entries already run (after an interruption)
#   --accepted      run again only the netlists kausal accepted last time (after a change to
#                   the simulator or validate; refusals and ngspice's own runs are kept)
#   --only TEXT     run only the netlists whose `repo:path` contains TEXT (the summary still covers
#                   every entry run so far)
#   --list FILE     run only the netlists named in FILE (`repo:path`, one a line)
#   --jobs N        N directories at once (one directory's netlists one after another, as ngspice
#                   writes files next to them; default 1). Each kausal/ngspice pair still runs
#                   one after the other, but beside N - 1 other jobs: its times are noisier.
# Limits (seconds): CORPUS_NGSPICE_TIMEOUT=60 CORPUS_CHECK_TIMEOUT=60 CORPUS_SIM_TIMEOUT=120
#   CORPUS_VALIDATE_TIMEOUT=120; CORPUS_MEM_LIMIT_GB=8 (address space of each process).
# ngspice runs each netlist as its authors wrote it, `.control` section included, and some of
# those write files next to the netlist (plot_data_v.txt, *.raw): the corpus directory is
# scratch space; scripts/corpus-fetch.sh puts the original files back.
# The machine may be shared: run it under `nice -n 10`.
set -euo pipefail

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
write=0
mode=run
extra=()
pos=()
while [[ $# -gt 0 ]]; do
    case $1 in
        --write) write=1 ;;
        --summary-only) mode=summary ;;
        --resume) extra+=(--resume) ;;
        --accepted) extra+=(--accepted) ;;
        --only) extra+=(--only "$2"); shift ;;
        --list) extra+=(--list "$(cd "$(dirname "$2")" && pwd)/$(basename "$2")"); shift ;;
        --jobs) extra+=(--jobs "$2"); shift ;;
        -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
        --) shift; pos+=("$@"); break ;;
        -*) echo "corpus.sh: unknown option '$1'" >&2; exit 2 ;;
        *) pos+=("$1") ;;
    esac
    shift
done

corpus=${pos[0]:-${KAUSAL_CORPUS:-$root/../corpus}}
manifest=${pos[1]:-${KAUSAL_MANIFEST:-$root/../shared/corpus/MANIFEST.tsv}}
kausal=${pos[2]:-${KAUSAL_BIN:-${CARGO_TARGET_DIR:-$root/target}/release/kausal}}

[[ -d $corpus ]] || { echo "corpus.sh: no corpus directory at $corpus (see scripts/corpus-fetch.sh)" >&2; exit 2; }
[[ -f $manifest ]] || { echo "corpus.sh: no manifest at $manifest" >&2; exit 2; }
corpus=$(cd "$corpus" && pwd)
manifest=$(cd "$(dirname "$manifest")" && pwd)/$(basename "$manifest")

if [[ $mode == run ]]; then
    command -v ngspice >/dev/null || { echo "corpus.sh: ngspice is not on the PATH" >&2; exit 2; }
    if [[ ! -x $kausal ]]; then
        echo "corpus.sh: building kausal ($kausal is missing)" >&2
        (cd "$root" && cargo build --release)
    fi
    [[ -x $kausal ]] || { echo "corpus.sh: no kausal binary at $kausal" >&2; exit 2; }
    kausal=$(cd "$(dirname "$kausal")" && pwd)/$(basename "$kausal")
fi

args=("$mode" --corpus "$corpus" --manifest "$manifest" --kausal "$kausal" --out "$root/target/corpus")
[[ $write == 1 ]] && args+=(--write "$root/VALIDATION.md")
exec python3 "$root/scripts/corpus.py" "${args[@]}" "${extra[@]}"
