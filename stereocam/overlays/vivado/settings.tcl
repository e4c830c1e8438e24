# settings.tcl: the constants every stereocam Vivado script shares. Sourced by package_ip.tcl,
# block_design.tcl and build.tcl; sourcing it twice changes nothing.
#
# tests/overlays/test_overlay_build.py reads these lines as text and checks them against stereocam/overlays/spec/.

# The Vivado release these scripts were written for: the one PYNQ 3.0's board images were built with.
# Other releases warn (build.tcl); their IP versions may differ from the VLNVs in block_design.tcl.
set STEREOCAM_VIVADO_VERSION 2022.1

# The device of SYSTEM.md, "The board".
set STEREOCAM_PART xc7z020clg400-1

# A board part (e.g. tul.com.tw:pynq-z2:part0:1.0, once its board files are installed) makes
# block_design.tcl apply the board's PS7 preset (DDR, MIO). Empty: the PS7's defaults. A PYNQ
# overlay does not depend on them (the image's boot loader configured the PS; pynq takes only
# the PL clock frequencies from the .hwh), but a hardware platform (.xsa) for a boot image would.
set STEREOCAM_BOARD_PART ""

# The board: its pin map is pins/$STEREOCAM_BOARD.pins (build.tcl -pins), named for the board profile
# (stereocam/board/<name>.yaml, name:) whose sensors and I2C bus it wires.
set STEREOCAM_BOARD zynq-stereo

# What the block design holds (build.tcl -build): colour, the rectify core's colour build as the board
# runs it today; depth, that and the stereo core with its own VDMA (stereocam/overlays/STEREO_CORE.md).
# Both are written as stereocam.bit/.hwh: the daemon finds the stereo core in the .hwh.
set STEREOCAM_BUILDS {colour depth}

# Block design name, and the overlay's file names: stereocam.bit + stereocam.hwh
# (stereocam/overlays/spec/overlay.py: BITSTREAM; pynq needs the .hwh beside the .bit under the same name).
set STEREOCAM_BD_NAME stereocam
set STEREOCAM_OVERLAY stereocam

# The one fabric clock, FCLK_CLK0, for the AXI4-Lite registers, the streams and the HP ports
# (stereocam/overlays/spec/overlay.py: FABRIC_CLOCK_HZ; tests/overlays/test_overlay_build.py checks they agree).
# The rectify core takes 2 clocks per beat (stereocam/overlays/spec/rectify.py: CLOCKS_PER_BEAT): 100 MHz
# is 50 Mbeat/s, 1.9x the MT9V034's pixel clock (26.6 MHz, a beat per pixel clock within a line)
# and 2.3x a 752x480 frame at 60 fps (21.7 Mbeat/s). Each VDMA channel has an HP port of its own,
# 64 bits x 100 MHz = 800 MB/s; a channel at 60 fps needs at most 173 MB/s (vdma_depth's 32-bit
# beats half that).
set STEREOCAM_FCLK0_MHZ 100

# Where things are (overridable: set them before sourcing to package another checkout's RTL).
set STEREOCAM_VIVADO_DIR [file dirname [file normalize [info script]]]
if {![info exists STEREOCAM_OVERLAYS_DIR]} {
    set STEREOCAM_OVERLAYS_DIR [file dirname $STEREOCAM_VIVADO_DIR]
}
if {![info exists STEREOCAM_RTL_DIR]} {
    set STEREOCAM_RTL_DIR [file join $STEREOCAM_OVERLAYS_DIR rtl]
}
