#!/usr/bin/env bash
# Build the stereocam overlay with Vivado: stereocam.bit and stereocam.hwh (see README.md here).
#
#   stereocam/overlays/vivado/build.sh [-out DIR] [-proj DIR] [-pins FILE] [-xdc FILE] [-jobs N] [-build colour|depth]
#       [-to package|bd|synth|impl|bit]
#
# The options are build.tcl's. Needs `vivado` on PATH: source <Xilinx>/Vivado/2022.1/settings64.sh
# first. Vivado runs in stereocam/overlays/vivado/build/ (its journal, log and .Xil folder stay there); relative
# paths in the options are taken from the folder build.sh was started in.
set -euo pipefail

here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
if ! command -v vivado >/dev/null 2>&1; then
    echo "build.sh: vivado is not on PATH; source <Xilinx>/Vivado/2022.1/settings64.sh first" >&2
    exit 1
fi
export STEREOCAM_CALLER_DIR="$PWD"
mkdir -p "$here/build"
cd "$here/build"
exec vivado -mode batch -notrace -log vivado.log -journal vivado.jou -source "$here/build.tcl" -tclargs "$@"
