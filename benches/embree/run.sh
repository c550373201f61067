#!/usr/bin/env bash
# sheaf against Embree 3 on the same triangles and the same rays.
#
#   benches/embree/run.sh            # the full run: 1024x1024, OBJ scenes + built-ins, then the
#                                    # two-level scene, 1 and 2 threads
#   benches/embree/run.sh --quick    # smoke test: builtin:tetra at 256x256, one timed run
#   benches/embree/run.sh --twolevel # the two-level scene alone (its section of the doc only)
#   benches/embree/run.sh --twolevel --quick  # its smoke test: builtin:gears, 256x256, 3 frames
#
# Options: --quick, --reps N (default 3), --size WxH (default 1024x1024),
# --scenes a,b,... (legocar, bunny, sibenik, sponza, conference, builtin names,
# or .obj paths), --threads 1,2, --counters (link sheaf with its `counters`
# feature; default: without, as an engine would ship it),
# --no-install (never apt-get).
# Two-level scene (`embree_bench --twolevel`, see README.md):
# --twolevel (run it alone), --no-twolevel (leave it out of the default run),
# --env NAME (its static environment: sponza (default), conference, a builtin
# name or an .obj path; without sponza's OBJ the default falls back to
# conference), --frames N (frames per run, default 24; --quick runs 3). It
# runs in the default full run (no --scenes) after the single scenes, and
# with --twolevel, which runs it alone (--scenes is then ignored).
# --filter: the two-level scene again with its animated geometry
# alpha-tested by any-hit filters in both libraries (a second table).
#
# 1. Installs Debian's libembree-dev with apt-get when it is missing and this
#    runs as root; otherwise prints "Embree 3 not installed: skipped" and exits 0.
# 2. Builds sheaf's static library into target/embree-bench/ (its own target
#    directory, so the default build's features are left alone) and the
#    `sheaf` CLI (cargo build --release -p sheaf-cli).
# 3. Exports each scene with its view and light (`sheaf export`), builds
#    benches/embree/embree_bench.c and runs it: progress on stderr, Markdown
#    on stdout. The full run (no --scenes) also writes docs/bench-embree/README.md (the
#    two-level scene as its last section, which --twolevel replaces alone).
set -euo pipefail
cd "$(dirname "$0")/../.."
ROOT=$PWD
export CARGO_TERM_COLOR=never

quick=0 reps=3 size=1024x1024 scenes="" threads=1,2 counters=0 install=1
twolevel=auto twolevel_asked=0 env="" tl_frames=24 tl_filter=0
while [ $# -gt 0 ]; do
  case "$1" in
    --quick) quick=1 ;;
    --twolevel) twolevel=only ;;
    --no-twolevel) twolevel=no twolevel_asked=1 ;;
    --env) env=$2; shift ;;
    --frames) tl_frames=$2; shift ;;
    --filter) tl_filter=1 ;;
    --reps) reps=$2; shift ;;
    --size) size=$2; shift ;;
    --scenes) scenes=$2; shift ;;
    --threads) threads=$2; shift ;;
    --counters) counters=1 ;;
    --no-install) install=0 ;;
    -h|--help) sed -n '2,/^set -euo/p' "$0" | sed '$d'; exit 0 ;;
    *) echo "run.sh: unknown option $1 (see --help)" >&2; exit 1 ;;
  esac
  shift
done
# The two-level scene runs alone (--twolevel), or after the single scenes
# of the default full run (no --scenes, not --quick, not --no-twolevel).
if [ $twolevel = auto ]; then
  if [ $quick = 0 ] && [ -z "$scenes" ]; then twolevel=after; else twolevel=no; fi
fi
anim_frames=48
if [ $quick = 1 ]; then
  reps=1 size=256x256
  [ -n "$scenes" ] || scenes=tetra
  # The two-level smoke test: a small built-in environment, few frames.
  [ -n "$env" ] || env=gears
  tl_frames=3 anim_frames=4
fi
scenes_asked=0
[ -z "$scenes" ] || scenes_asked=1
[ -n "$scenes" ] || scenes=legocar,bunny,sibenik,sponza,conference,animated,balls

# ---- Embree 3 ---------------------------------------------------------------
have_embree() {
  [ -f /usr/include/embree3/rtcore.h ] && ldconfig -p 2>/dev/null | grep 'libembree3\.so' >/dev/null
}
if ! have_embree && [ $install = 1 ] && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
  echo "== installing libembree-dev (Debian's Embree 3) with apt-get" >&2
  { apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends libembree-dev; } >&2 \
    || echo "run.sh: apt-get install libembree-dev failed" >&2
fi
if ! have_embree; then
  echo "Embree 3 not installed: skipped (install Debian's libembree-dev, as root: apt-get install libembree-dev)"
  exit 0
fi
for tool in gcc make cargo; do
  command -v "$tool" >/dev/null 2>&1 || { echo "run.sh: $tool is needed" >&2; exit 1; }
done

# ---- sheaf ----------------------------------------------------------------------
out=$ROOT/target/embree-bench
mkdir -p "$out/scenes"
if [ $counters = 1 ]; then
  features=(--features std,counters) feat_note="features std, counters"
else
  features=(--no-default-features --features std) feat_note="--no-default-features --features std (no counters)"
fi
echo "== cargo build -p sheaf --release --lib ${features[*]} (target/embree-bench)" >&2
# -p sheaf: from the workspace root a plain build also selects sheaf-cli,
# whose `cli` feature would switch the counters on in this library too.
CARGO_TARGET_DIR=$out cargo build -p sheaf --release --lib "${features[@]}" >&2
echo "== cargo build --release -p sheaf-cli" >&2
cargo build --release -p sheaf-cli >&2
sheaf=$ROOT/target/release/sheaf

# ---- scenes ---------------------------------------------------------------------
shared=$ROOT/../shared/scenes
# scene_src NAME: the OBJ path or builtin:NAME of a scene name (empty: unknown).
scene_src() {
  case "$1" in
    legocar) echo "$shared/legocar/legocar.obj" ;;
    bunny) echo "$shared/bunny/bunny_tinybvh.obj" ;;
    sibenik) echo "$shared/sibenik/sibenik.obj" ;;
    sponza) echo "$shared/crytek_sponza/crytek_sponza.obj" ;;
    conference) echo "$shared/conference/conference.obj" ;;
    tetra|balls|gears|animated) echo "builtin:$1" ;;
    builtin:*|*.obj) echo "$1" ;;
  esac
}
# export_scene SRC [FRAMES]: `sheaf export` at --size into $out/scenes; sets $f.
export_scene() {
  local src=$1 frames=()
  f=$out/scenes/$(basename "${src#builtin:}" .obj)-$size.scene
  if [ -n "${2:-}" ]; then
    frames=(--frames "$2")
    f=${f%.scene}-f$2.scene
  fi
  echo "== sheaf export $src --size $size ${frames[*]}" >&2
  "$sheaf" export "$src" --size "$size" --out "$f" "${frames[@]}" >&2
}
files=()
if [ $twolevel != only ]; then
  IFS=, read -r -a names <<< "$scenes"
  for n in "${names[@]}"; do
    src=$(scene_src "$n")
    [ -n "$src" ] || { echo "run.sh: unknown scene $n" >&2; exit 1; }
    if [ "${src#builtin:}" = "$src" ] && [ ! -f "$src" ]; then
      echo "note: $n: $src not found, skipped" >&2
      continue
    fi
    # The animated scene carries its animation: per-frame rebuild and refit rows.
    if [ "$n" = animated ]; then export_scene "$src" 48; else export_scene "$src"; fi
    files+=("$f")
  done
  [ ${#files[@]} -gt 0 ] || { echo "run.sh: no scene to run" >&2; exit 1; }
fi
# The two-level scene: ENV (static), builtin:animated with its frames, builtin:tetra.
tl_files=()
if [ $twolevel != no ]; then
  env_src=$(scene_src "${env:-sponza}")
  [ -n "$env_src" ] || { echo "run.sh: unknown --env ${env}" >&2; exit 1; }
  if [ -z "$env" ] && [ ! -f "$env_src" ]; then
    echo "note: two-level scene: $env_src not found, trying conference" >&2
    env_src=$(scene_src conference)
  fi
  if [ "${env_src#builtin:}" = "$env_src" ] && [ ! -f "$env_src" ]; then
    echo "note: two-level scene: $env_src not found, skipped" >&2
    [ $twolevel = only ] && exit 1
    twolevel=no
  else
    export_scene "$env_src"; tl_files+=("$f")
    export_scene builtin:animated "$anim_frames"; tl_files+=("$f")
    export_scene builtin:tetra; tl_files+=("$f")
  fi
fi

# ---- the program ------------------------------------------------------------------
echo "== make -C benches/embree" >&2
make -s -C benches/embree SHEAF_LIBDIR="$out/release" OUT="$out/embree_bench" >&2
cmd=(benches/embree/run.sh)
[ $quick = 1 ] && cmd+=(--quick)
[ $twolevel = only ] && cmd+=(--twolevel)
[ $twolevel = no ] && [ $twolevel_asked = 1 ] && cmd+=(--no-twolevel)
[ -n "$env" ] && [ $quick = 0 ] && [ $twolevel != no ] && cmd+=(--env "$env")
[ "$tl_frames" != 24 ] && [ $quick = 0 ] && [ $twolevel != no ] && cmd+=(--frames "$tl_frames")
[ $tl_filter = 1 ] && [ $twolevel != no ] && cmd+=(--filter)
[ "$reps" != 3 ] && [ $quick = 0 ] && cmd+=(--reps "$reps")
[ "$size" != 1024x1024 ] && [ $quick = 0 ] && cmd+=(--size "$size")
[ "$threads" != 1,2 ] && cmd+=(--threads "$threads")
[ $counters = 1 ] && cmd+=(--counters)
# Timings on a busy machine are noise: the full run waits (up to 10
# minutes) for the 1-minute load average to fall below 0.5 (the builds and
# exports above raise it, and so do the single scenes' 2-thread runs before
# the two-level scene).
wait_quiet() {
  [ $quick = 0 ] || return 0
  local waited=0
  for _ in $(seq 120); do
    awk '{exit !($1 >= 0.5)}' /proc/loadavg || break
    [ $waited = 0 ] && echo "== waiting for the load average to fall below 0.5 ($(cut -d' ' -f1 /proc/loadavg))" >&2
    waited=1
    sleep 5
  done
}
wait_quiet
load_before=$(cut -d' ' -f1-3 /proc/loadavg)
started=$(date -u '+%Y-%m-%d %H:%M UTC')
t0=$(date +%s)
tables=$out/tables.md tl_tables=$out/tables-twolevel.md
if [ $twolevel != only ]; then
  set +e
  "$out/embree_bench" --reps "$reps" --threads "$threads" --summary "$out/summary.txt" "${files[@]}" | tee "$tables"
  status=${PIPESTATUS[0]}
  set -e
  [ "$status" = 0 ] || { echo "run.sh: embree_bench failed ($status)" >&2; exit "$status"; }
fi
secs=$(( $(date +%s) - t0 ))
load_after=$(cut -d' ' -f1-3 /proc/loadavg)
if [ $twolevel != no ]; then
  wait_quiet
  tl_load_before=$(cut -d' ' -f1-3 /proc/loadavg)
  tl_started=$(date -u '+%Y-%m-%d %H:%M UTC')
  tl_t0=$(date +%s)
  tl_check=()
  [ $quick = 1 ] && tl_check=(--check) # the smoke test fails on disagreement
  set +e
  "$out/embree_bench" --twolevel "${tl_files[@]}" --frames "$tl_frames" --reps "$reps" --threads "$threads" \
    --summary "$out/summary-twolevel.txt" "${tl_check[@]}" | tee "$tl_tables"
  status=${PIPESTATUS[0]}
  set -e
  [ "$status" = 0 ] || { echo "run.sh: embree_bench --twolevel failed ($status)" >&2; exit "$status"; }
  if [ $tl_filter = 1 ]; then
    wait_quiet
    set +e
    "$out/embree_bench" --twolevel "${tl_files[@]}" --frames "$tl_frames" --reps "$reps" --threads "$threads" \
      --filter --summary "$out/summary-twolevel-filter.txt" "${tl_check[@]}" | tee -a "$tl_tables"
    status=${PIPESTATUS[0]}
    set -e
    [ "$status" = 0 ] || { echo "run.sh: embree_bench --twolevel --filter failed ($status)" >&2; exit "$status"; }
  fi
  tl_secs=$(( $(date +%s) - tl_t0 ))
  tl_load_after=$(cut -d' ' -f1-3 /proc/loadavg)
fi

# The two-level section of the doc (its own header: it may be replaced alone).
twolevel_section() {
  echo "## Two-level scene (an engine frame: static environment, animated and instanced objects)"
  echo
  echo "Generated by \`${cmd[*]}\` on $tl_started in ${tl_secs} s (\`embree_bench --twolevel\`, $tl_frames frames"
  echo "per run, median of $reps runs). Load average (1, 5, 15 min) before: $tl_load_before; after: $tl_load_after."
  echo "One engine frame loop in both libraries over the same instances and rays: a static environment,"
  echo "\`builtin:animated\` refit every frame (4 instances), \`builtin:tetra\` in a ring of 16 instances"
  echo "turning every frame; per frame update + commit, the environment's camera rays and their shadow rays."
  echo "See benches/embree/README.md (\"Two-level scene\") for how it is put together and measured."
  echo
  cat "$tl_tables"
}

doc=$ROOT/docs/bench-embree/README.md
if [ $quick = 0 ] && [ $twolevel = only ]; then
  # Replace the two-level section (the doc's last) or append it.
  mkdir -p "$(dirname "$doc")"
  rev=$(git rev-parse --short HEAD 2>/dev/null || echo unknown)
  git diff --quiet HEAD 2>/dev/null || rev="$rev (with uncommitted changes)"
  {
    if [ -f "$doc" ]; then
      # Everything before the old section, without trailing blank lines.
      awk '/^## Two-level scene/ {exit} /^$/ {blank++; next} {for (; blank > 0; blank--) print ""; print}' "$doc"
    else
      echo "# sheaf against Embree 3"
      echo
      echo "Written by \`benches/embree/run.sh --twolevel\` alone (sheaf $rev; $(rustc --version 2>/dev/null || echo rustc);"
      echo "$(gcc --version | head -1); sheaf built with $feat_note); a full run (\`benches/embree/run.sh\`)"
      echo "puts the single-scene tables before this section."
    fi
    echo
    twolevel_section
  } > "$doc.tmp"
  mv "$doc.tmp" "$doc"
  echo "== wrote the two-level section of ${doc#"$ROOT"/}" >&2
fi

# Only the full run (no --scenes) rewrites the doc: a run over some scenes
# prints its tables and leaves the full run's doc alone.
if [ $quick = 0 ] && [ $twolevel != only ] && [ $scenes_asked = 0 ]; then
  mkdir -p "$(dirname "$doc")"
  rev=$(git rev-parse --short HEAD 2>/dev/null || echo unknown)
  git diff --quiet HEAD 2>/dev/null || rev="$rev (with uncommitted changes)"
  {
    echo "# sheaf against Embree 3"
    echo
    echo "Generated by \`${cmd[*]}\` on $started in ${secs} s (sheaf $rev;"
    echo "$(rustc --version 2>/dev/null || echo rustc); $(gcc --version | head -1); sheaf built with $feat_note)."
    echo "Load average (1, 5, 15 min) before: $load_before; after: $load_after. The machine is"
    echo "shared with other work: 2-thread figures in particular vary from run to run."
    echo
    echo "Every scene is exported by \`sheaf export\` (\`cli/src/cmd/export.rs\`) with the view and light"
    echo "\`sheaf render\` picks, and traced by \`benches/embree/embree_bench.c\` with sheaf through its C ABI"
    echo "and with Embree 3 on the same triangles (one Embree geometry with sheaf's index buffer, so"
    echo "Embree's primID is sheaf's triangle index) and bit-identical rays: camera rays from"
    echo "\`sheaf_frame_camera_ray\`, shadow rays made as sheaf's renderers make them, checked bit for bit"
    echo "against a sheaf deferred frame. Ratios are sheaf / Embree: above 1 sheaf is faster for"
    echo "Mrays/s, slower for frame times. See benches/embree/README.md for what is measured."
    if [ -f "$(dirname "$doc")/earlier-run.md" ]; then
      echo "An earlier run, to show the run-to-run spread: [earlier-run.md](earlier-run.md)."
    fi
    echo
    cat "$tables"
    if [ $twolevel = after ]; then
      echo
      twolevel_section
    fi
  } > "$doc"
  echo "== wrote ${doc#"$ROOT"/}" >&2
fi
