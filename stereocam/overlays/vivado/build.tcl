# build.tcl: build the stereocam overlay (stereocam.bit + stereocam.hwh) with Vivado in batch mode.
#
#   stereocam/overlays/vivado/build.sh [options]
#   vivado -mode batch -source stereocam/overlays/vivado/build.tcl -tclargs [options]
#
# Options (one or two leading dashes):
#   -out DIR    where stereocam.bit and stereocam.hwh go. Default: stereocam/overlays/ of this checkout, the first
#               folder `stereocam --backend pynq` looks in (stereocam/overlays/backend.py: DEFAULT_BITSTREAM_DIRS).
#   -proj DIR   the Vivado project and the packaged IP. Default: stereocam/overlays/vivado/build/stereocam.
#   -pins FILE  the board's pin map: one line per external port bit (port, package pin, I/O standard,
#               properties). Default: pins/$STEREOCAM_BOARD.pins beside this script (settings.tcl), whose
#               pins are placeholders (FILL_IN): implementation refuses it until they are filled in.
#   -xdc FILE   the timing constraints. Default: stereocam.xdc beside this script.
#   -jobs N     parallel synthesis/implementation jobs. Default: 2.
#   -build B    what the overlay holds ($STEREOCAM_BUILDS in settings.tcl): colour (the default: the
#               rectify core's colour build) or depth (that, and the stereo core with its own VDMA,
#               stereocam/overlays/STEREO_CORE.md). Either is written as stereocam.bit and stereocam.hwh.
#   -to STEP    stop after STEP: package (the IP), bd (block design, wrapper, output products),
#               synth, impl (placed and routed), bit (the default: bitstream and .hwh copied to -out).
#
# The flow follows PYNQ's boards/<board>/base/build_bitstream.tcl: package the IP (package_ip.tcl),
# create the project and the block design (block_design.tcl), validate it, make its HDL wrapper,
# synthesise, implement, write the bitstream, and copy the bitstream and the hardware handoff under
# the overlay's name (pynq wants the .hwh beside the .bit with the same name).

set stereocam_here [file dirname [file normalize [info script]]]
source [file join $stereocam_here settings.tcl]

set stereocam_steps {package bd synth impl bit}

# Options as a dict: $defaults with the values given in $arguments (-name value or --name value).
proc stereocam_parse_args {arguments defaults} {
    set opts $defaults
    while {[llength $arguments] > 0} {
        set arguments [lassign $arguments flag]
        set name [string trimleft $flag -]
        if {$name eq $flag || ![dict exists $opts $name]} {
            error "build.tcl: unknown option '$flag' (options: -[join [dict keys $defaults] {, -}])"
        }
        if {[llength $arguments] == 0} {
            error "build.tcl: option '$flag' needs a value"
        }
        set arguments [lassign $arguments value]
        dict set opts $name $value
    }
    return $opts
}

# A path given on the command line, relative to where the user ran build.sh.
proc stereocam_path {path} {
    if {[info exists ::env(STEREOCAM_CALLER_DIR)] && [file pathtype $path] eq "relative"} {
        set path [file join $::env(STEREOCAM_CALLER_DIR) $path]
    }
    return [file normalize $path]
}

# The pin map $path as a list of {port pin iostandard {NAME value ...}}, one per line that is not a
# comment; a malformed line stops the build with its number.
proc stereocam_read_pins {path} {
    set fd [open $path r]
    set text [read $fd]
    close $fd
    set entries {}
    set number 0
    foreach line [split $text "\n"] {
        incr number
        set line [string trim $line]
        if {$line eq "" || [string index $line 0] eq "#"} {
            continue
        }
        set words [regexp -all -inline {\S+} $line]
        if {[llength $words] < 3} {
            error "build.tcl: $path line $number: expected 'port package_pin iostandard \[NAME=value ...\]',\
                   got '$line'"
        }
        set props {}
        foreach word [lrange $words 3 end] {
            set eq [string first = $word]
            if {$eq < 1} {
                error "build.tcl: $path line $number: '$word' is not a NAME=value property"
            }
            lappend props [string range $word 0 [expr {$eq - 1}]] [string range $word [expr {$eq + 1}] end]
        }
        lappend entries [list [lindex $words 0] [lindex $words 1] [lindex $words 2] $props]
    }
    return $entries
}

# Fail unless run $run completed.
proc stereocam_check_run {run} {
    set progress [get_property PROGRESS [get_runs $run]]
    if {$progress ne "100%"} {
        set log [file join [get_property DIRECTORY [get_runs $run]] runme.log]
        error "build.tcl: $run stopped at $progress ([get_property STATUS [get_runs $run]]): see $log"
    }
}

if {![info exists argv]} {
    set argv {}
}
set stereocam_opts [stereocam_parse_args $argv [dict create \
    out $STEREOCAM_OVERLAYS_DIR \
    proj [file join $STEREOCAM_VIVADO_DIR build $STEREOCAM_BD_NAME] \
    pins [file join $STEREOCAM_VIVADO_DIR pins $STEREOCAM_BOARD.pins] \
    xdc [file join $STEREOCAM_VIVADO_DIR stereocam.xdc] \
    jobs 2 \
    build colour \
    to bit]]
set stereocam_out [stereocam_path [dict get $stereocam_opts out]]
set stereocam_proj [stereocam_path [dict get $stereocam_opts proj]]
set stereocam_xdc [stereocam_path [dict get $stereocam_opts xdc]]
set stereocam_pins [stereocam_path [dict get $stereocam_opts pins]]
set stereocam_jobs [dict get $stereocam_opts jobs]
set stereocam_last [lsearch -exact $stereocam_steps [dict get $stereocam_opts to]]
if {$stereocam_last < 0} {
    error "build.tcl: -to must be one of [join $stereocam_steps {, }], not '[dict get $stereocam_opts to]'"
}
set STEREOCAM_BUILD [dict get $stereocam_opts build]
if {[lsearch -exact $STEREOCAM_BUILDS $STEREOCAM_BUILD] < 0} {
    error "build.tcl: -build must be one of [join $STEREOCAM_BUILDS {, }], not '$STEREOCAM_BUILD'"
}
if {![string is integer -strict $stereocam_jobs] || $stereocam_jobs < 1} {
    error "build.tcl: -jobs must be a positive number, not '$stereocam_jobs'"
}

set stereocam_found [version -short]
if {[string first $STEREOCAM_VIVADO_VERSION $stereocam_found] != 0} {
    puts "WARNING: stereocam: these scripts were written for Vivado $STEREOCAM_VIVADO_VERSION and this is\
          $stereocam_found: if an IP version differs, create_bd_cell names the VLNV it could not find."
}

# The constraints: the timing constraints, and the board's pins, whose placeholders are refused before
# hours of work, unless only synthesis was asked for.
set stereocam_synth [lsearch -exact $stereocam_steps synth]
if {$stereocam_last >= $stereocam_synth && ![file isfile $stereocam_xdc]} {
    error "build.tcl: no constraints file $stereocam_xdc"
}
set stereocam_use_pins 0
if {![file isfile $stereocam_pins]} {
    if {$stereocam_last > $stereocam_synth} {
        error "build.tcl: no pin map $stereocam_pins: copy pins/zynq-stereo.pins beside this script, fill in\
               your board's pins and pass -pins <your copy>"
    }
} else {
    set stereocam_pin_map [stereocam_read_pins $stereocam_pins]
    set stereocam_unfilled {}
    foreach stereocam_entry $stereocam_pin_map {
        if {[lindex $stereocam_entry 1] eq "FILL_IN"} {
            lappend stereocam_unfilled [lindex $stereocam_entry 0]
        }
    }
    if {[llength $stereocam_unfilled] == 0} {
        set stereocam_use_pins 1
    } elseif {$stereocam_last > $stereocam_synth} {
        error "build.tcl: the pin map $stereocam_pins still has placeholder pins (FILL_IN) for\
               [llength $stereocam_unfilled] ports: [join $stereocam_unfilled {, }]. Fill in your board's\
               pins (see the comments at its top), or stop after synthesis with -to synth."
    } else {
        puts "WARNING: stereocam: $stereocam_pins has placeholder pins (FILL_IN): synthesis without them."
    }
}

puts "stereocam: Vivado $stereocam_found, the $STEREOCAM_BUILD build, project $stereocam_proj, outputs to\
      $stereocam_out"

# ---- 1. package the IP (before the project: Vivado holds one project at a time) ---------------------
set STEREOCAM_IP_REPO [file join $stereocam_proj ip_repo]
set STEREOCAM_IP_BUILD [file join $stereocam_proj ip_build]
source [file join $STEREOCAM_VIVADO_DIR package_ip.tcl]
if {$stereocam_last == [lsearch -exact $stereocam_steps package]} {
    puts "stereocam: IP packaged in $STEREOCAM_IP_REPO"
    return
}

# ---- 2. the project, the block design, its wrapper and output products -----------------------------
create_project -force $STEREOCAM_BD_NAME $stereocam_proj -part $STEREOCAM_PART
if {$STEREOCAM_BOARD_PART ne ""} {
    set_property board_part $STEREOCAM_BOARD_PART [current_project]
}
set_property target_language Verilog [current_project]
set_property ip_repo_paths [list $STEREOCAM_IP_REPO] [current_project]
update_ip_catalog -rebuild

source [file join $STEREOCAM_VIVADO_DIR block_design.tcl]
validate_bd_design
save_bd_design

set stereocam_bd [get_files $STEREOCAM_BD_NAME.bd]
add_files -norecurse [make_wrapper -files $stereocam_bd -top]
set_property top ${STEREOCAM_BD_NAME}_wrapper [current_fileset]
update_compile_order -fileset sources_1
generate_target all $stereocam_bd
if {[file isfile $stereocam_xdc]} {
    add_files -fileset constrs_1 -norecurse $stereocam_xdc
}
if {$stereocam_use_pins} {
    # The pin map as constraints, in the project: what Vivado places is what the map says.
    set stereocam_pins_xdc [file join $stereocam_proj pins.xdc]
    set stereocam_fd [open $stereocam_pins_xdc w]
    puts $stereocam_fd "# Written by build.tcl from $stereocam_pins: edit that file, not this one."
    foreach stereocam_entry $stereocam_pin_map {
        lassign $stereocam_entry stereocam_port stereocam_pin stereocam_std stereocam_props
        set stereocam_dict [dict create PACKAGE_PIN $stereocam_pin IOSTANDARD $stereocam_std {*}$stereocam_props]
        puts $stereocam_fd "set_property -dict {$stereocam_dict} \[get_ports {$stereocam_port}\]"
    }
    close $stereocam_fd
    add_files -fileset constrs_1 -norecurse $stereocam_pins_xdc
}
if {$stereocam_last == [lsearch -exact $stereocam_steps bd]} {
    puts "stereocam: block design ready in $stereocam_proj"
    return
}

# ---- 3. synthesis ------------------------------------------------------------------------------------
launch_runs synth_1 -jobs $stereocam_jobs
wait_on_run synth_1
stereocam_check_run synth_1
if {$stereocam_last == [lsearch -exact $stereocam_steps synth]} {
    puts "stereocam: synthesised; reports in [get_property DIRECTORY [get_runs synth_1]]"
    return
}

# ---- 4. implementation and bitstream ---------------------------------------------------------------
if {$stereocam_last == [lsearch -exact $stereocam_steps impl]} {
    launch_runs impl_1 -jobs $stereocam_jobs
} else {
    launch_runs impl_1 -to_step write_bitstream -jobs $stereocam_jobs
}
wait_on_run impl_1
stereocam_check_run impl_1
set stereocam_impl_dir [get_property DIRECTORY [get_runs impl_1]]

# Routed timing is the sign-off (`stereocam hw timing` only estimates it): write the timing summary
# beside the bitstream, and stop when any setup (WNS) or hold (WHS) slack is negative.
open_run impl_1
set stereocam_timing [file join $stereocam_impl_dir $STEREOCAM_OVERLAY.timing.rpt]
report_timing_summary -max_paths 10 -file $stereocam_timing
set stereocam_wns [get_property SLACK [get_timing_paths -delay_type max -max_paths 1 -nworst 1]]
set stereocam_whs [get_property SLACK [get_timing_paths -delay_type min -max_paths 1 -nworst 1]]
foreach {stereocam_kind stereocam_slack} [list WNS $stereocam_wns WHS $stereocam_whs] {
    if {$stereocam_slack ne "" && $stereocam_slack < 0} {
        error "build.tcl: routed timing fails: $stereocam_kind $stereocam_slack ns at\
            $STEREOCAM_FCLK0_MHZ MHz; no overlay written. Read $stereocam_timing, then pipeline the path\
            (stereocam hw timing lists the estimated worst ones) or lower STEREOCAM_FCLK0_MHZ in settings.tcl"
    }
}
puts "stereocam: routed WNS $stereocam_wns ns, WHS $stereocam_whs ns; summary in $stereocam_timing"
if {$stereocam_last == [lsearch -exact $stereocam_steps impl]} {
    puts "stereocam: implemented; reports in $stereocam_impl_dir"
    return
}

# ---- 5. the overlay: <out>/stereocam.bit and <out>/stereocam.hwh -----------------------------------
set stereocam_bit [file join $stereocam_impl_dir ${STEREOCAM_BD_NAME}_wrapper.bit]
# The hardware handoff: under <project>.gen in recent releases, under <project>.srcs in older ones.
set stereocam_hwh ""
foreach stereocam_dir [list $STEREOCAM_BD_NAME.gen $STEREOCAM_BD_NAME.srcs] {
    set stereocam_candidate [file join $stereocam_proj $stereocam_dir sources_1 bd $STEREOCAM_BD_NAME \
        hw_handoff $STEREOCAM_BD_NAME.hwh]
    if {$stereocam_hwh eq "" && [file isfile $stereocam_candidate]} {
        set stereocam_hwh $stereocam_candidate
    }
}
if {![file isfile $stereocam_bit]} {
    error "build.tcl: impl_1 finished but wrote no $stereocam_bit"
}
if {$stereocam_hwh eq ""} {
    error "build.tcl: no hardware handoff $STEREOCAM_BD_NAME.hwh under $stereocam_proj"
}
file mkdir $stereocam_out
file copy -force $stereocam_bit [file join $stereocam_out $STEREOCAM_OVERLAY.bit]
file copy -force $stereocam_hwh [file join $stereocam_out $STEREOCAM_OVERLAY.hwh]
file copy -force $stereocam_timing [file join $stereocam_out $STEREOCAM_OVERLAY.timing.rpt]
puts "stereocam: wrote [file join $stereocam_out $STEREOCAM_OVERLAY.bit], with $STEREOCAM_OVERLAY.hwh and\
    $STEREOCAM_OVERLAY.timing.rpt beside it"
