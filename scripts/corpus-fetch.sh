#!/usr/bin/env bash
# corpus-fetch.sh — lay out the public netlist corpus outside the repository.
#
# The corpus is other people's files: ngspice's examples (imr/ngspice), eSim's
# examples (FOSSEE/eSim), Xyce's regression decks (Xyce/Xyce_Regression) and
# ahkab's tests (ahkab/ahkab). MANIFEST.tsv lists them as `repository<TAB>path`
# (first line a header). None of it is committed here; `scripts/corpus.sh`
# reads it from the corpus directory and `VALIDATION.md` holds only its summary.
#
# Layout written (CORPUS defaults to ../corpus next to the repository root):
#
#   CORPUS/<owner>+<name>/<path>       every listed netlist, at its path in its repository,
#                                      with the whole directory that holds it (sub-directories
#                                      included), so `.include`/`.lib`/data files beside it resolve;
#   CORPUS/<owner>+<name>/<other>      files outside that directory that a listed netlist (or a
#                                      file it includes) names in `.include`/`.inc`/`.lib`,
#                                      followed recursively, relative to the including file;
#   CORPUS/SOURCES.tsv                 repository, commit and mirror each file came from.
#
# Where the repositories come from. This script reads bare (or normal) git
# repositories, one per manifest repository, at MIRRORS/<owner>+<name>/repo
# (MIRRORS defaults to ../.mirror next to the repository root, or $KAUSAL_MIRRORS).
# It cannot obtain them by itself in a sandbox without network: there they are
# brought in by the tool library's `fetch` (source `github:<owner>/<name>`,
# which leaves exactly that layout under /work/.mirror). With network, pass
# --clone and it runs `git clone --bare --depth 1 https://github.com/<owner>/<name>`
# into MIRRORS/<owner>+<name>/repo for every repository that is missing there.
# A snapshot may lack its largest blobs; those files are skipped (and counted).
#
# Usage: scripts/corpus-fetch.sh [--clone] [--corpus DIR] [--manifest FILE] [--mirrors DIR]
#   env: KAUSAL_CORPUS, KAUSAL_MANIFEST, KAUSAL_MIRRORS
set -euo pipefail

root=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
corpus=${KAUSAL_CORPUS:-$root/../corpus}
manifest=${KAUSAL_MANIFEST:-$root/../shared/corpus/MANIFEST.tsv}
mirrors=${KAUSAL_MIRRORS:-$root/../.mirror}
clone=0

while [[ $# -gt 0 ]]; do
    case $1 in
        --clone) clone=1 ;;
        --corpus) corpus=$2; shift ;;
        --manifest) manifest=$2; shift ;;
        --mirrors) mirrors=$2; shift ;;
        -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d; s/^# \{0,1\}//'; exit 0 ;;
        *) echo "corpus-fetch.sh: unknown argument '$1'" >&2; exit 2 ;;
    esac
    shift
done

[[ -f $manifest ]] || { echo "corpus-fetch.sh: no manifest at $manifest" >&2; exit 2; }
mkdir -p "$corpus" "$mirrors"
corpus=$(cd "$corpus" && pwd)
mirrors=$(cd "$mirrors" && pwd)

# Repositories named in the manifest (column 1, header skipped).
mapfile -t repos < <(tail -n +2 "$manifest" | cut -f1 | sort -u)

for repo in "${repos[@]}"; do
    [[ $repo =~ ^[A-Za-z0-9][A-Za-z0-9_.-]*/[A-Za-z0-9][A-Za-z0-9_.-]*$ ]] \
        || { echo "corpus-fetch.sh: bad repository name '$repo'" >&2; exit 2; }
    gitdir=$mirrors/${repo/\//+}/repo
    if ! git --git-dir="$gitdir" rev-parse --verify -q HEAD >/dev/null 2>&1; then
        if [[ $clone == 1 ]]; then
            mkdir -p "$mirrors/${repo/\//+}"
            timeout 1800 git clone --bare --depth 1 "https://github.com/$repo" "$gitdir"
        else
            echo "corpus-fetch.sh: no mirror of $repo at $gitdir" >&2
            echo "  get it with the tool library's fetch (github:$repo) or rerun with --clone" >&2
            exit 1
        fi
    fi
done

MIRRORS=$mirrors CORPUS=$corpus MANIFEST=$manifest python3 - <<'PY'
import collections, os, posixpath, re, subprocess, sys

mirrors, corpus, manifest = os.environ["MIRRORS"], os.environ["CORPUS"], os.environ["MANIFEST"]

entries = []
with open(manifest, encoding="utf-8") as f:
    next(f)
    for line in f:
        line = line.rstrip("\n")
        if not line:
            continue
        repo, path = line.split("\t", 1)
        entries.append((repo, path))

by_repo = collections.defaultdict(list)
for repo, path in entries:
    by_repo[repo].append(path)

INCLUDE = re.compile(r"^\s*\.(?:include|inc|lib)\s+(\"[^\"]+\"|'[^']+'|\S+)", re.I)


class Repo:
    def __init__(self, name):
        self.gitdir = os.path.join(mirrors, name.replace("/", "+"), "repo")
        self.commit = subprocess.run(["git", "--git-dir", self.gitdir, "rev-parse", "HEAD"],
                                     check=True, capture_output=True, text=True).stdout.strip()
        out = subprocess.run(["git", "--git-dir", self.gitdir, "ls-tree", "-r", "-z", "HEAD"],
                             check=True, capture_output=True).stdout
        self.blobs = {}
        for rec in out.split(b"\0"):
            if not rec:
                continue
            meta, p = rec.split(b"\t", 1)
            mode, kind, sha = meta.split()
            if kind == b"blob" and mode != b"120000":
                self.blobs[p.decode("utf-8", "surrogateescape")] = sha.decode()
        self.cat = subprocess.Popen(["git", "--git-dir", self.gitdir, "cat-file", "--batch"],
                                    stdin=subprocess.PIPE, stdout=subprocess.PIPE)

    def read(self, path):
        """The blob's bytes, or None when the snapshot lacks it."""
        sha = self.blobs.get(path)
        if sha is None:
            return None
        self.cat.stdin.write(sha.encode() + b"\n")
        self.cat.stdin.flush()
        header = self.cat.stdout.readline().split()
        if len(header) < 3 or header[1] != b"blob":
            return None
        data = self.cat.stdout.read(int(header[2]))
        self.cat.stdout.read(1)
        return data


written = missing = 0
sources = []
for name, paths in sorted(by_repo.items()):
    r = Repo(name)
    base = os.path.join(corpus, name.replace("/", "+"))
    wanted = set()
    dirs = {posixpath.dirname(p) for p in paths}
    for p in r.blobs:
        if any(d == "" or p.startswith(d + "/") for d in dirs):
            wanted.add(p)
    wanted.update(paths)
    # Follow .include/.lib out of those directories (relative to the including file).
    todo = list(paths)
    seen = set(todo)
    while todo:
        p = todo.pop()
        data = r.read(p)
        if data is None or len(data) > 16 << 20:
            continue
        for line in data.decode("utf-8", "replace").splitlines():
            m = INCLUDE.match(line)
            if not m:
                continue
            target = m.group(1).strip("\"'")
            if target.startswith(("/", "~")) or re.match(r"^[A-Za-z]:", target):
                continue
            q = posixpath.normpath(posixpath.join(posixpath.dirname(p), target.replace("\\", "/")))
            if q.startswith("../") or q not in r.blobs or q in seen:
                continue
            seen.add(q)
            wanted.add(q)
            todo.append(q)
    n_missing = 0
    for p in sorted(wanted):
        dest = os.path.join(base, p)
        if os.path.normpath(dest) != dest or not dest.startswith(base + "/"):
            continue
        data = r.read(p)
        if data is None:
            n_missing += 1
            continue
        os.makedirs(os.path.dirname(dest), exist_ok=True)
        try:
            with open(dest, "rb") as f:
                if f.read() == data:
                    continue
        except OSError:
            pass
        with open(dest, "wb") as f:
            f.write(data)
        written += 1
    absent = [p for p in paths if p not in r.blobs or not os.path.isfile(os.path.join(base, p))]
    print(f"{name}: {len(paths)} listed, {len(wanted)} files wanted, "
          f"{n_missing} absent from the snapshot, {len(absent)} listed files absent, commit {r.commit}")
    missing += len(absent)
    sources.append((name, r.commit, r.gitdir))
    r.cat.stdin.close()
    r.cat.wait()

with open(os.path.join(corpus, "SOURCES.tsv"), "w", encoding="utf-8") as f:
    f.write("repository\tcommit\tmirror\n")
    for s in sources:
        f.write("\t".join(s) + "\n")
print(f"{written} files written under {corpus}; {missing} listed netlists absent")
PY
