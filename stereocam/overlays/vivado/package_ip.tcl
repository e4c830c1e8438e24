# package_ip.tcl: package the stereocam RTL as Vivado IP (IP-XACT, with the ipx:: commands of UG1118).
#
#   stereocam:user:rectify:2.0     stereocam/overlays/rtl/rectify_core.v, rc_*.v, *.vh (rectify_spec.vh,
#                                  rc_regs_decode.vh, prelude.vh) (stereocam/overlays/spec/rectify.py: VLNV,
#                                  DEFAULT_BUILD)
#   stereocam:user:camera_in:1.0   stereocam/overlays/rtl/camera/camera_in.v, ci_*.v, *.vh, ../rc_ram.v,
#                                  ../rc_fifo.v, ../rc_gray.v, ../prelude.vh
#                                  (stereocam/overlays/spec/camera_in.py: VLNV, TOP, PORTS, PARAMETERS)
#   stereocam:user:frame_gate:1.0  stereocam/overlays/rtl/camera/frame_gate.v, ../rc_ram.v, ../rc_fifo.v,
#                                  ../prelude.vh (stereocam/overlays/spec/frame_gate.py: VLNV, TOP, SOURCES,
#                                  PORTS, PARAMETERS)
#   stereocam:user:stereo:1.0      stereocam/overlays/rtl/stereo/stereo_core.v, sc_*.v, *.vh, ../rc_ram.v,
#                                  ../rc_fifo.v, ../prelude.vh (stereocam/overlays/spec/stereo.py: VLNV,
#                                  DEFAULT_BUILD);
#                                  only the depth build's block design instantiates it
#
# Each IP is packaged from a throw-away project of its own (Vivado holds one project at a time, so
# build.tcl sources this file before it creates the overlay's project). The cores land in
# $STEREOCAM_IP_REPO/rectify, .../camera_in, .../frame_gate and .../stereo, with their sources copied in.
#
# Sourced by build.tcl, which sets STEREOCAM_IP_REPO and STEREOCAM_IP_BUILD; alone:
#   vivado -mode batch -source stereocam/overlays/vivado/package_ip.tcl -tclargs <ip_repo_dir>
#
# The packager infers the bus interfaces from the port names (s_axil_*, s_axis_*, m_axis_*, aclk,
# aresetn); the checks below fail loudly when it did not. tests/overlays/test_overlay_build.py checks the
# identities and parameters here against stereocam/overlays/spec/ and the RTL's module headers.

source [file join [file dirname [file normalize [info script]]] settings.tcl]
# The register window and the user parameters of each IP (STEREOCAM_IP_WINDOW, STEREOCAM_IP_PARAMS),
# generated from stereocam/overlays/spec/ (python -m stereocam.overlays.spec.verilog).
source [file join $STEREOCAM_VIVADO_DIR ip_params.tcl]

if {![info exists STEREOCAM_IP_REPO]} {
    if {[info exists argv] && [llength $argv] > 0} {
        set STEREOCAM_IP_REPO [file normalize [lindex $argv 0]]
    } else {
        set STEREOCAM_IP_REPO [file normalize ip_repo]
    }
}
if {![info exists STEREOCAM_IP_BUILD]} {
    set STEREOCAM_IP_BUILD [file join [file dirname $STEREOCAM_IP_REPO] ip_build]
}

# ---- helpers: the mechanics both IPs share; the values that matter are in the calls below -----------

# Create the packaging project $name holding $sources, with module $top at the top.
proc stereocam_packaging_project {name top sources} {
    global STEREOCAM_PART STEREOCAM_IP_BUILD
    if {[llength $sources] == 0} {
        error "stereocam: no sources for $name (top module $top)"
    }
    create_project -force $name [file join $STEREOCAM_IP_BUILD $name] -part $STEREOCAM_PART
    add_files -norecurse $sources
    foreach header [lsearch -all -inline -glob $sources *.vh] {
        set_property file_type {Verilog Header} [get_files $header]
    }
    set_property top $top [current_fileset]
    update_compile_order -fileset sources_1
}

# Fail unless the packager made each bus interface in $names (a port named differently than the
# spec says ends up as a plain wire, and the block design could not connect it).
proc stereocam_require_interfaces {core names} {
    foreach name $names {
        if {[ipx::get_bus_interfaces $name -of_objects $core] eq ""} {
            error "stereocam: [get_property NAME $core] has no bus interface '$name': check the top module's port names"
        }
    }
}

# Clock $clk runs the bus interfaces $busifs; $rst is its active-low synchronous reset.
proc stereocam_clock {core clk rst busifs} {
    set reset [ipx::get_bus_interfaces $rst -of_objects $core]
    set polarity [ipx::get_bus_parameters POLARITY -of_objects $reset]
    if {$polarity eq ""} {
        set polarity [ipx::add_bus_parameter POLARITY $reset]
    }
    set_property value ACTIVE_LOW $polarity
    foreach busif $busifs {
        ipx::associate_bus_interfaces -busif $busif -clock $clk $core
    }
    ipx::associate_bus_interfaces -clock $clk -reset $rst $core
}

# A clock input that runs no bus interface (a camera's pixel clock: its data pins are plain wires).
proc stereocam_free_clock {core port} {
    if {[ipx::get_bus_interfaces $port -of_objects $core] eq ""} {
        ipx::infer_bus_interface $port xilinx.com:signal:clock_rtl:1.0 $core
    }
}

# The AXI4-Lite slave $busif decodes $range bytes: one register block "reg0" (the block design's
# address segment is <cell>/$busif/reg0, and may map a larger window onto it) holding $registers,
# each {name byte_offset access reset_value} (the .hwh lists them, and pynq's register_map).
proc stereocam_register_window {core busif range {registers {}}} {
    foreach map [ipx::get_memory_maps -of_objects $core] {
        ipx::remove_memory_map [get_property NAME $map] $core
    }
    set map [ipx::add_memory_map $busif $core]
    set_property slave_memory_map_ref $busif [ipx::get_bus_interfaces $busif -of_objects $core]
    set block [ipx::add_address_block reg0 $map]
    set_property range $range $block
    set_property width 32 $block
    set_property usage register $block
    foreach reg $registers {
        lassign $reg name offset access reset
        set register [ipx::add_register $name $block]
        set_property address_offset $offset $register
        set_property size 32 $register
        set_property access $access $register
        set_property reset_value $reset $register
    }
}

# Verilog parameter $name as a user parameter: its default and the range the GUI accepts.
proc stereocam_user_param {core name default minimum maximum} {
    set param [ipx::get_user_parameters $name -of_objects $core]
    if {$param eq ""} {
        error "stereocam: [get_property NAME $core] has no parameter $name: check the top module's header"
    }
    set_property value_validation_type range_long $param
    set_property value_validation_range_minimum $minimum $param
    set_property value_validation_range_maximum $maximum $param
    set_property value $default $param
    set_property value $default [ipx::get_hdl_parameters $name -of_objects $core]
}

# Every user parameter of $ip in ip_params.tcl: {name default minimum maximum}.
proc stereocam_user_params {core ip} {
    global STEREOCAM_IP_PARAMS
    foreach param $STEREOCAM_IP_PARAMS($ip) {
        stereocam_user_param $core {*}$param
    }
}

# Write the GUI files and checksums, check the core, save it and close its packaging project.
proc stereocam_save_core {core} {
    set_property core_revision 1 $core
    ipx::create_xgui_files $core
    ipx::update_checksums $core
    ipx::check_integrity $core
    ipx::save_core $core
    close_project
}

# ---- stereocam:user:rectify:2.0 (stereocam/overlays/spec/rectify.py: VLNV) -------------------------------------

set rectify_sources [concat \
    [list [file join $STEREOCAM_RTL_DIR rectify_core.v]] \
    [lsort [glob -nocomplain -directory $STEREOCAM_RTL_DIR rc_*.v]] \
    [lsort [glob -nocomplain -directory $STEREOCAM_RTL_DIR *.vh]]]

stereocam_packaging_project pkg_rectify rectify_core $rectify_sources
ipx::package_project -root_dir [file join $STEREOCAM_IP_REPO rectify] -vendor stereocam -library user \
    -taxonomy /UserIP -import_files -set_current true -force
set core [ipx::current_core]
set_property name rectify $core
set_property version 2.0 $core
set_property display_name {stereocam rectify core} $core
set_property description {Stereo rectification and lens undistortion at pixel rate (RECTIFY_CORE.md)} \
    $core
set_property supported_families {zynq Production} $core
stereocam_require_interfaces $core {aclk aresetn s_axil s_axis m_axis}
stereocam_clock $core aclk aresetn {s_axil s_axis m_axis}
# The register map (RECTIFY_MAP.size bytes); the block design maps a 64 KiB window onto it.
stereocam_register_window $core s_axil $STEREOCAM_IP_WINDOW(rectify) $STEREOCAM_IP_REGISTERS(rectify)
# Build parameters: defaults DEFAULT_BUILD (the colour build), ranges BUILD_LIMITS (spec/rectify.py).
stereocam_user_params $core rectify
stereocam_save_core $core

# ---- stereocam:user:camera_in:1.0 (stereocam/overlays/spec/camera_in.py: VLNV) ---------------------------------

# camera_in.v and its ci_*.v modules, and the RAM and FIFO it shares with the rectify core; the folder's
# other top (frame_gate.v) is an IP of its own.
set camera_dir [file join $STEREOCAM_RTL_DIR camera]
if {![file exists [file join $camera_dir camera_in.v]]} {
    error "stereocam: no camera input RTL (camera_in.v) in $camera_dir: the camera_in IP cannot be packaged"
}
set camera_sources [concat \
    [list [file join $camera_dir camera_in.v]] \
    [lsort [glob -nocomplain -directory $camera_dir ci_*.v]] \
    [list [file join $STEREOCAM_RTL_DIR rc_ram.v] [file join $STEREOCAM_RTL_DIR rc_fifo.v] \
          [file join $STEREOCAM_RTL_DIR rc_gray.v] [file join $STEREOCAM_RTL_DIR prelude.vh]] \
    [lsort [glob -nocomplain -directory $camera_dir *.vh]]]

stereocam_packaging_project pkg_camera_in camera_in $camera_sources
ipx::package_project -root_dir [file join $STEREOCAM_IP_REPO camera_in] -vendor stereocam -library user \
    -taxonomy /UserIP -import_files -set_current true -force
set core [ipx::current_core]
set_property name camera_in $core
set_property version 1.0 $core
set_property display_name {stereocam camera input} $core
set_property description {Two MT9V034 parallel receivers and the Bayer demosaic: the 64-bit stereo stream} $core
set_property supported_families {zynq Production} $core
stereocam_require_interfaces $core {aclk aresetn m_axis}
stereocam_clock $core aclk aresetn {m_axis}
stereocam_free_clock $core cam0_pclk
stereocam_free_clock $core cam1_pclk
# Parameters: defaults camera_in.PARAMETERS. MAX_WIDTH: MIN_WIDTH up to MAX_WIDTH_LIMIT (the line
# FIFOs' length field); BAYER_PHASE: a CFA_PHASES code, the default for the driver's full-size window
# (a window of another start parity needs another build).
stereocam_user_params $core camera_in
stereocam_save_core $core

# ---- stereocam:user:frame_gate:1.0 (stereocam/overlays/spec/frame_gate.py: VLNV, SOURCES) -------------------------
# Two instances in the block design (gate_raw, gate_live): an AXI4-Stream slave that is always ready and
# a master that forwards whole frames through a block RAM FIFO of DEPTH beats.

set gate_sources {}
foreach name {frame_gate.v ../rc_ram.v ../rc_fifo.v ../prelude.vh} {
    set path [file join $camera_dir $name]
    if {![file exists $path]} {
        error "stereocam: no $name in $camera_dir: the frame_gate IP cannot be packaged"
    }
    lappend gate_sources $path
}

stereocam_packaging_project pkg_frame_gate frame_gate $gate_sources
ipx::package_project -root_dir [file join $STEREOCAM_IP_REPO frame_gate] -vendor stereocam -library user \
    -taxonomy /UserIP -import_files -set_current true -force
set core [ipx::current_core]
set_property name frame_gate $core
set_property version 1.0 $core
set_property display_name {stereocam frame gate} $core
set_property description {Always takes its input; forwards whole frames, drops those its output cannot take} \
    $core
set_property supported_families {zynq Production} $core
stereocam_require_interfaces $core {aclk aresetn s_axis m_axis}
stereocam_clock $core aclk aresetn {s_axis m_axis}
# Parameters: defaults frame_gate.PARAMETERS, range frame_gate.DEPTH_RANGE.
stereocam_user_params $core frame_gate
stereocam_save_core $core

# ---- stereocam:user:stereo:1.0 (stereocam/overlays/spec/stereo.py: VLNV; STEREO_CORE.md) -------------------------
# The stereo core and the RAM and FIFO it shares with the rectify core (stereo_sources() in
# stereocam/overlays/rtl/stereo_core.py lists the same files for the simulators and yosys).

set stereo_dir [file join $STEREOCAM_RTL_DIR stereo]
if {![file exists [file join $stereo_dir stereo_core.v]]} {
    error "stereocam: no stereo core RTL (stereo_core.v) in $stereo_dir: the stereo IP cannot be packaged"
}
set stereo_sources [concat \
    [list [file join $stereo_dir stereo_core.v]] \
    [lsort [glob -nocomplain -directory $stereo_dir sc_*.v]] \
    [list [file join $STEREOCAM_RTL_DIR rc_ram.v] [file join $STEREOCAM_RTL_DIR rc_fifo.v] \
          [file join $STEREOCAM_RTL_DIR prelude.vh]] \
    [lsort [glob -nocomplain -directory $stereo_dir *.vh]]]

stereocam_packaging_project pkg_stereo stereo_core $stereo_sources
ipx::package_project -root_dir [file join $STEREOCAM_IP_REPO stereo] -vendor stereocam -library user \
    -taxonomy /UserIP -import_files -set_current true -force
set core [ipx::current_core]
set_property name stereo $core
set_property version 1.0 $core
set_property display_name {stereocam stereo core} $core
set_property description {Census and semi-global matching of the rectified pair at pixel rate (STEREO_CORE.md)} \
    $core
set_property supported_families {zynq Production} $core
stereocam_require_interfaces $core {aclk aresetn s_axil s_axis m_axis}
stereocam_clock $core aclk aresetn {s_axil s_axis m_axis}
# The register map (STEREO_MAP.size bytes); the block design maps a 64 KiB window onto it.
stereocam_register_window $core s_axil $STEREOCAM_IP_WINDOW(stereo) $STEREOCAM_IP_REGISTERS(stereo)
# Build parameters: defaults DEFAULT_BUILD (the depth build), ranges BUILD_LIMITS (spec/stereo.py);
# MAX_DISP must be 4 x PARALLEL, which the RTL checks when it is elaborated.
stereocam_user_params $core stereo
stereocam_save_core $core
