# block_design.tcl: the stereocam overlay's block design (SYSTEM.md, "The fabric"), for xc7z020clg400-1.
#
#  cam0/cam1 pins -> camera_in -> camera_split -+-> gate_raw  -> vdma_raw S2MM ----------------> HP0 (DDR)
#                                               +-> gate_live -> mux S00 -+
#  DDR (HP1) -> vdma_proc MM2S ---------------------------------> mux S01 -+-> mux M00 -> rectify
#                                                                                 -> vdma_proc S2MM -> HP2
#
# The depth build ($STEREOCAM_BUILD depth, build.tcl -build depth) adds the stereo core on the rectified
# stream (stereocam/overlays/spec/overlay.py: OPTIONAL_INSTANCES, STEREO_CORE.md):
#
#  rectify -> rectified_split -+-> vdma_proc S2MM -> HP2
#                              +-> stereo -> vdma_depth S2MM -> HP3
#
# Each VDMA master has an HP port of its own, through a 1:1 AXI interconnect (the usual Zynq
# arrangement, as in PYNQ's board designs): no arbitration between the channels in the fabric, and
# the interconnect is only the AXI4 -> AXI3 protocol converter the HP ports need (PG059).
#
# Sourced by build.tcl into an open project whose IP catalogue holds the packaged cores (package_ip.tcl).
# Written in the style of Vivado's write_bd_tcl (PYNQ's boards/*/base/base.tcl): one cell per
# create_bd_cell, its configuration in one set_property -dict, literal values. The names, VLNVs,
# parameters and addresses are the ones stereocam/overlays/spec/ gives the drivers and the emulated fabric;
# tests/overlays/test_overlay_build.py checks them against it.
#
# One clock, FCLK_CLK0 ($STEREOCAM_FCLK0_MHZ MHz, settings.tcl), runs everything but the cameras'
# pixel clocks, which camera_in crosses into it; one proc_sys_reset drives every reset.

source [file join [file dirname [file normalize [info script]]] settings.tcl]
if {![info exists STEREOCAM_BUILD]} {
    set STEREOCAM_BUILD colour
}
if {[lsearch -exact $STEREOCAM_BUILDS $STEREOCAM_BUILD] < 0} {
    error "block_design.tcl: STEREOCAM_BUILD must be one of [join $STEREOCAM_BUILDS {, }], not '$STEREOCAM_BUILD'"
}

create_bd_design $STEREOCAM_BD_NAME

# ---- Zynq PS7: M_AXI_GP0 for the registers, S_AXI_HP0..HP2 (HP3 in the depth build) for the frames,
# FCLK_CLK0, IRQ_F2P, and I2C0 through EMIO to the sensors' two-wire interface ------------------------------

create_bd_cell -type ip -vlnv xilinx.com:ip:processing_system7:5.5 processing_system7_0
if {$STEREOCAM_BOARD_PART ne ""} {
    set stereocam_ps7_preset 1
} else {
    set stereocam_ps7_preset 0
}
apply_bd_automation -rule xilinx.com:bd_rule:processing_system7 \
    -config [list make_external {FIXED_IO, DDR} apply_board_preset $stereocam_ps7_preset \
                 Master Disable Slave Disable] \
    [get_bd_cells processing_system7_0]
set_property -dict [list \
    CONFIG.PCW_USE_M_AXI_GP0 {1} \
    CONFIG.PCW_USE_S_AXI_HP0 {1} \
    CONFIG.PCW_S_AXI_HP0_DATA_WIDTH {64} \
    CONFIG.PCW_USE_S_AXI_HP1 {1} \
    CONFIG.PCW_S_AXI_HP1_DATA_WIDTH {64} \
    CONFIG.PCW_USE_S_AXI_HP2 {1} \
    CONFIG.PCW_S_AXI_HP2_DATA_WIDTH {64} \
    CONFIG.PCW_EN_CLK0_PORT {1} \
    CONFIG.PCW_EN_RST0_PORT {1} \
    CONFIG.PCW_FPGA_FCLK0_ENABLE {1} \
    CONFIG.PCW_FPGA0_PERIPHERAL_FREQMHZ $STEREOCAM_FCLK0_MHZ \
    CONFIG.PCW_USE_FABRIC_INTERRUPT {1} \
    CONFIG.PCW_IRQ_F2P_INTR {1} \
    CONFIG.PCW_I2C0_PERIPHERAL_ENABLE {1} \
    CONFIG.PCW_I2C0_I2C0_IO {EMIO} \
] [get_bd_cells processing_system7_0]
# The depth build: HP3 for vdma_depth S2MM.
if {$STEREOCAM_BUILD eq "depth"} {
    set_property -dict [list \
        CONFIG.PCW_USE_S_AXI_HP3 {1} \
        CONFIG.PCW_S_AXI_HP3_DATA_WIDTH {64} \
    ] [get_bd_cells processing_system7_0]
}

create_bd_cell -type ip -vlnv xilinx.com:ip:proc_sys_reset:5.0 rst_ps7_0

# ---- AXI: registers through an interconnect on GP0, frames through one 1:1 interconnect per HP port ---

# M00 vdma_raw, M01 vdma_proc, M02 rectify, M03 mux
create_bd_cell -type ip -vlnv xilinx.com:ip:axi_interconnect:2.1 axi_ctrl
set_property -dict [list \
    CONFIG.NUM_SI {1} \
    CONFIG.NUM_MI {4} \
] [get_bd_cells axi_ctrl]

# One per VDMA master, to an HP port of its own; 64 bits and FCLK_CLK0 on both sides, so with one SI
# and one MI PG059 builds no crossbar, width or clock converter: only the AXI4 -> AXI3 protocol
# converter (PG059, "AXI Protocol Converter"; the HP ports are AXI3).
# axi_mem_raw: vdma_raw S2MM -> HP0
create_bd_cell -type ip -vlnv xilinx.com:ip:axi_interconnect:2.1 axi_mem_raw
set_property -dict [list \
    CONFIG.NUM_SI {1} \
    CONFIG.NUM_MI {1} \
] [get_bd_cells axi_mem_raw]

# axi_mem_proc_rd: vdma_proc MM2S -> HP1
create_bd_cell -type ip -vlnv xilinx.com:ip:axi_interconnect:2.1 axi_mem_proc_rd
set_property -dict [list \
    CONFIG.NUM_SI {1} \
    CONFIG.NUM_MI {1} \
] [get_bd_cells axi_mem_proc_rd]

# axi_mem_proc_wr: vdma_proc S2MM -> HP2
create_bd_cell -type ip -vlnv xilinx.com:ip:axi_interconnect:2.1 axi_mem_proc_wr
set_property -dict [list \
    CONFIG.NUM_SI {1} \
    CONFIG.NUM_MI {1} \
] [get_bd_cells axi_mem_proc_wr]

# The depth build: M04 stereo, M05 vdma_depth on GP0; axi_mem_depth: vdma_depth S2MM -> HP3.
if {$STEREOCAM_BUILD eq "depth"} {
    set_property -dict [list \
        CONFIG.NUM_MI {6} \
    ] [get_bd_cells axi_ctrl]

    create_bd_cell -type ip -vlnv xilinx.com:ip:axi_interconnect:2.1 axi_mem_depth
    set_property -dict [list \
        CONFIG.NUM_SI {1} \
        CONFIG.NUM_MI {1} \
    ] [get_bd_cells axi_mem_depth]
}

# ---- The camera input IP (stereocam/overlays/spec/camera_in.py), the split of its stream and the frame gates ----

create_bd_cell -type ip -vlnv stereocam:user:camera_in:1.0 camera_in
set_property -dict [list \
    CONFIG.MAX_WIDTH {752} \
    CONFIG.BAYER_PHASE {3} \
] [get_bd_cells camera_in]

# One 64-bit beat per pixel position of both cameras (stereocam/overlays/spec/pixel.py), TUSER = start of frame,
# TLAST = end of line, to both vdma_raw and the mux's live input. A broadcaster passes a beat only
# when every output takes it (PG085), so each output goes through a frame gate, which always takes
# it: neither path can hold the other or the cameras.
create_bd_cell -type ip -vlnv xilinx.com:ip:axis_broadcaster:1.1 camera_split
set_property -dict [list \
    CONFIG.NUM_MI {2} \
    CONFIG.S_TDATA_NUM_BYTES {8} \
    CONFIG.M_TDATA_NUM_BYTES {8} \
    CONFIG.S_TUSER_WIDTH {1} \
    CONFIG.M_TUSER_WIDTH {1} \
    CONFIG.HAS_TLAST {1} \
    CONFIG.HAS_TKEEP {0} \
    CONFIG.HAS_TSTRB {0} \
] [get_bd_cells camera_split]

# The frame gates (stereocam/overlays/spec/frame_gate.py): s_axis_tready always high; each forwards whole frames
# (or, after a stall longer than its FIFO absorbs, a frame's first whole lines) and drops whole frames
# while its consumer does not take them. gate_raw: M00 -> vdma_raw; gate_live: M01 -> mux S00.
create_bd_cell -type ip -vlnv stereocam:user:frame_gate:1.0 gate_raw
set_property -dict [list \
    CONFIG.DEPTH {1024} \
] [get_bd_cells gate_raw]

create_bd_cell -type ip -vlnv stereocam:user:frame_gate:1.0 gate_live
set_property -dict [list \
    CONFIG.DEPTH {1024} \
] [get_bd_cells gate_live]

# ---- VDMAs (PG020): register direct mode, 64-bit streams, start of frame on TUSER ----------------------
# c_mm2s_max_burst_length / c_s2mm_max_burst_length 16: AXI3's longest burst, so each channel's bursts
# reach its HP port (AXI3) through the interconnect's protocol converter whole, never split.
# c_use_s2mm_fsync 2 = "s2mm tuser": an S2MM frame starts at the beat with TUSER set.
# c_use_mm2s_fsync 0 = free running: the virtual camera sends frames as fast as the core takes them.
# The S2MM stream width is propagated from the stream it is connected to unless marked USER.

# vdma_raw: S2MM only, raw camera frames to DDR.
create_bd_cell -type ip -vlnv xilinx.com:ip:axi_vdma:6.3 vdma_raw
set_property -dict [list \
    CONFIG.c_m_axi_s2mm_data_width.VALUE_SRC USER \
    CONFIG.c_s_axis_s2mm_tdata_width.VALUE_SRC USER \
] [get_bd_cells vdma_raw]
set_property -dict [list \
    CONFIG.c_include_sg {0} \
    CONFIG.c_include_mm2s {0} \
    CONFIG.c_include_s2mm {1} \
    CONFIG.c_num_fstores {3} \
    CONFIG.c_addr_width {32} \
    CONFIG.c_m_axi_s2mm_data_width {64} \
    CONFIG.c_s_axis_s2mm_tdata_width {64} \
    CONFIG.c_s2mm_linebuffer_depth {512} \
    CONFIG.c_s2mm_max_burst_length {16} \
    CONFIG.c_include_s2mm_dre {0} \
    CONFIG.c_s2mm_genlock_mode {0} \
    CONFIG.c_use_s2mm_fsync {2} \
    CONFIG.c_s2mm_sof_enable {1} \
] [get_bd_cells vdma_raw]

# vdma_proc: MM2S is the virtual camera (DDR -> mux S01), S2MM writes the rectified frames to DDR.
create_bd_cell -type ip -vlnv xilinx.com:ip:axi_vdma:6.3 vdma_proc
set_property -dict [list \
    CONFIG.c_m_axi_s2mm_data_width.VALUE_SRC USER \
    CONFIG.c_s_axis_s2mm_tdata_width.VALUE_SRC USER \
] [get_bd_cells vdma_proc]
set_property -dict [list \
    CONFIG.c_include_sg {0} \
    CONFIG.c_include_mm2s {1} \
    CONFIG.c_include_s2mm {1} \
    CONFIG.c_num_fstores {3} \
    CONFIG.c_addr_width {32} \
    CONFIG.c_m_axi_mm2s_data_width {64} \
    CONFIG.c_m_axis_mm2s_tdata_width {64} \
    CONFIG.c_mm2s_linebuffer_depth {512} \
    CONFIG.c_mm2s_max_burst_length {16} \
    CONFIG.c_include_mm2s_dre {0} \
    CONFIG.c_mm2s_genlock_mode {0} \
    CONFIG.c_use_mm2s_fsync {0} \
    CONFIG.c_mm2s_sof_enable {1} \
    CONFIG.c_m_axi_s2mm_data_width {64} \
    CONFIG.c_s_axis_s2mm_tdata_width {64} \
    CONFIG.c_s2mm_linebuffer_depth {512} \
    CONFIG.c_s2mm_max_burst_length {16} \
    CONFIG.c_include_s2mm_dre {0} \
    CONFIG.c_s2mm_genlock_mode {0} \
    CONFIG.c_use_s2mm_fsync {2} \
    CONFIG.c_s2mm_sof_enable {1} \
] [get_bd_cells vdma_proc]

# ---- The source mux (PG085, stereocam/overlays/spec/axis_switch.py): SI0 live, SI1 virtual, MI0 -> rectify -----
# ROUTING_MODE 1 = control register routing: an AXI4-Lite slave (S_AXI_CTRL) with MI0_MUX at 0x40.
create_bd_cell -type ip -vlnv xilinx.com:ip:axis_switch:1.1 mux
set_property -dict [list \
    CONFIG.NUM_SI {2} \
    CONFIG.NUM_MI {1} \
    CONFIG.ROUTING_MODE {1} \
] [get_bd_cells mux]

# ---- The rectify core (stereocam/overlays/spec/rectify.py: DEFAULT_BUILD) ---------------------------------------
create_bd_cell -type ip -vlnv stereocam:user:rectify:2.0 rectify
set_property -dict [list \
    CONFIG.MAX_WIDTH {752} \
    CONFIG.MAX_HEIGHT {1024} \
    CONFIG.LB_ROWS {80} \
    CONFIG.COLOUR {1} \
] [get_bd_cells rectify]
# The depth build has the gray rectify core: the colour build's block RAM and the stereo core's
# would not fit the xc7z020 together (stereocam hw synth --build depth; STEREO_CORE.md).
if {$STEREOCAM_BUILD eq "depth"} {
    set_property -dict [list \
        CONFIG.COLOUR {0} \
    ] [get_bd_cells rectify]
}

# ---- The depth build's stereo core (stereocam/overlays/spec/stereo.py: DEFAULT_BUILD), the split that feeds
# it the rectified pixels, and its output channel -----------------------------------------------------------
if {$STEREOCAM_BUILD eq "depth"} {
    # Both outputs take every rectified beat: a broadcaster passes a beat when both take it (PG085),
    # so a frame reaches vdma_proc and the stereo core alike, or neither, and frame store k of
    # vdma_depth holds the disparity of frame store k of vdma_proc.
    create_bd_cell -type ip -vlnv xilinx.com:ip:axis_broadcaster:1.1 rectified_split
    set_property -dict [list \
        CONFIG.NUM_MI {2} \
        CONFIG.S_TDATA_NUM_BYTES {8} \
        CONFIG.M_TDATA_NUM_BYTES {8} \
        CONFIG.S_TUSER_WIDTH {1} \
        CONFIG.M_TUSER_WIDTH {1} \
        CONFIG.HAS_TLAST {1} \
        CONFIG.HAS_TKEEP {0} \
        CONFIG.HAS_TSTRB {0} \
    ] [get_bd_cells rectified_split]

    create_bd_cell -type ip -vlnv stereocam:user:stereo:1.0 stereo
    set_property -dict [list \
        CONFIG.MAX_WIDTH {752} \
        CONFIG.MAX_HEIGHT {1024} \
        CONFIG.MAX_DISP {128} \
        CONFIG.PARALLEL {32} \
    ] [get_bd_cells stereo]

    # vdma_depth: S2MM only, the stereo core's 32-bit beats to DDR. The VDMA packs two to a 64-bit
    # memory word, the left pixel in the low half (spec/overlay.py: DEPTH_PIXELS_PER_BEAT), so the
    # driver starts it width / 2 eight-byte pixels wide. Genlock slave of vdma_proc's S2MM
    # (s2mm_frame_ptr_in from its s2mm_frame_ptr_out).
    create_bd_cell -type ip -vlnv xilinx.com:ip:axi_vdma:6.3 vdma_depth
    set_property -dict [list \
        CONFIG.c_m_axi_s2mm_data_width.VALUE_SRC USER \
        CONFIG.c_s_axis_s2mm_tdata_width.VALUE_SRC USER \
    ] [get_bd_cells vdma_depth]
    set_property -dict [list \
        CONFIG.c_include_sg {0} \
        CONFIG.c_include_mm2s {0} \
        CONFIG.c_include_s2mm {1} \
        CONFIG.c_num_fstores {3} \
        CONFIG.c_addr_width {32} \
        CONFIG.c_m_axi_s2mm_data_width {64} \
        CONFIG.c_s_axis_s2mm_tdata_width {32} \
        CONFIG.c_s2mm_linebuffer_depth {512} \
        CONFIG.c_s2mm_max_burst_length {16} \
        CONFIG.c_include_s2mm_dre {0} \
        CONFIG.c_s2mm_genlock_mode {1} \
        CONFIG.c_use_s2mm_fsync {2} \
        CONFIG.c_s2mm_sof_enable {1} \
    ] [get_bd_cells vdma_depth]
}

# ---- Interrupts: the VDMA channels' introut, In0.. in this order, to IRQ_F2P ---------------------------
create_bd_cell -type ip -vlnv xilinx.com:ip:xlconcat:2.1 irq_concat
set_property -dict [list \
    CONFIG.NUM_PORTS {3} \
] [get_bd_cells irq_concat]
if {$STEREOCAM_BUILD eq "depth"} {
    set_property -dict [list \
        CONFIG.NUM_PORTS {4} \
    ] [get_bd_cells irq_concat]
}

# ---- Camera pins: external ports of the design (the board's pin map places them; the MT9V034's PIXCLK,
# DOUT[9:0], LINE_VALID, FRAME_VALID of the left (cam0) and right (cam1) sensor) ----------------------
create_bd_port -dir I -type clk -freq_hz 27000000 cam0_pclk
create_bd_port -dir I -from 9 -to 0 cam0_data
create_bd_port -dir I cam0_line_valid
create_bd_port -dir I cam0_frame_valid
create_bd_port -dir I -type clk -freq_hz 27000000 cam1_pclk
create_bd_port -dir I -from 9 -to 0 cam1_data
create_bd_port -dir I cam1_line_valid
create_bd_port -dir I cam1_frame_valid
connect_bd_net [get_bd_ports cam0_pclk] [get_bd_pins camera_in/cam0_pclk]
connect_bd_net [get_bd_ports cam0_data] [get_bd_pins camera_in/cam0_data]
connect_bd_net [get_bd_ports cam0_line_valid] [get_bd_pins camera_in/cam0_line_valid]
connect_bd_net [get_bd_ports cam0_frame_valid] [get_bd_pins camera_in/cam0_frame_valid]
connect_bd_net [get_bd_ports cam1_pclk] [get_bd_pins camera_in/cam1_pclk]
connect_bd_net [get_bd_ports cam1_data] [get_bd_pins camera_in/cam1_data]
connect_bd_net [get_bd_ports cam1_line_valid] [get_bd_pins camera_in/cam1_line_valid]
connect_bd_net [get_bd_ports cam1_frame_valid] [get_bd_pins camera_in/cam1_frame_valid]

# ---- The sensors' I2C: the PS7's I2C0 (EMIO) as the external interface port cam_iic, both sensors on it
# (stereocam/overlays/spec/overlay.py: SENSOR_I2C_*; the wrapper's IOBUFs give cam_iic_scl_io and
# cam_iic_sda_io, which the board's pin map places) ---------------------------------------------------
create_bd_intf_port -mode Master -vlnv xilinx.com:interface:iic_rtl:1.0 cam_iic
connect_bd_intf_net [get_bd_intf_pins processing_system7_0/IIC_0] [get_bd_intf_ports cam_iic]

# ---- Streams -----------------------------------------------------------------------------------------
connect_bd_intf_net [get_bd_intf_pins camera_in/m_axis] [get_bd_intf_pins camera_split/S_AXIS]
connect_bd_intf_net [get_bd_intf_pins camera_split/M00_AXIS] [get_bd_intf_pins gate_raw/s_axis]
connect_bd_intf_net [get_bd_intf_pins gate_raw/m_axis] [get_bd_intf_pins vdma_raw/S_AXIS_S2MM]
connect_bd_intf_net [get_bd_intf_pins camera_split/M01_AXIS] [get_bd_intf_pins gate_live/s_axis]
connect_bd_intf_net [get_bd_intf_pins gate_live/m_axis] [get_bd_intf_pins mux/S00_AXIS]
connect_bd_intf_net [get_bd_intf_pins vdma_proc/M_AXIS_MM2S] [get_bd_intf_pins mux/S01_AXIS]
connect_bd_intf_net [get_bd_intf_pins mux/M00_AXIS] [get_bd_intf_pins rectify/s_axis]
if {$STEREOCAM_BUILD eq "depth"} {
    connect_bd_intf_net [get_bd_intf_pins rectify/m_axis] [get_bd_intf_pins rectified_split/S_AXIS]
    connect_bd_intf_net [get_bd_intf_pins rectified_split/M00_AXIS] [get_bd_intf_pins vdma_proc/S_AXIS_S2MM]
    connect_bd_intf_net [get_bd_intf_pins rectified_split/M01_AXIS] [get_bd_intf_pins stereo/s_axis]
    connect_bd_intf_net [get_bd_intf_pins stereo/m_axis] [get_bd_intf_pins vdma_depth/S_AXIS_S2MM]
} else {
    connect_bd_intf_net [get_bd_intf_pins rectify/m_axis] [get_bd_intf_pins vdma_proc/S_AXIS_S2MM]
}

# ---- Register buses (GP0) ----------------------------------------------------------------------------
connect_bd_intf_net [get_bd_intf_pins processing_system7_0/M_AXI_GP0] [get_bd_intf_pins axi_ctrl/S00_AXI]
connect_bd_intf_net [get_bd_intf_pins axi_ctrl/M00_AXI] [get_bd_intf_pins vdma_raw/S_AXI_LITE]
connect_bd_intf_net [get_bd_intf_pins axi_ctrl/M01_AXI] [get_bd_intf_pins vdma_proc/S_AXI_LITE]
connect_bd_intf_net [get_bd_intf_pins axi_ctrl/M02_AXI] [get_bd_intf_pins rectify/s_axil]
connect_bd_intf_net [get_bd_intf_pins axi_ctrl/M03_AXI] [get_bd_intf_pins mux/S_AXI_CTRL]
if {$STEREOCAM_BUILD eq "depth"} {
    connect_bd_intf_net [get_bd_intf_pins axi_ctrl/M04_AXI] [get_bd_intf_pins stereo/s_axil]
    connect_bd_intf_net [get_bd_intf_pins axi_ctrl/M05_AXI] [get_bd_intf_pins vdma_depth/S_AXI_LITE]
}

# ---- Frame memory (HP0..HP2, HP3 in the depth build): each VDMA master through its interconnect ------
connect_bd_intf_net [get_bd_intf_pins vdma_raw/M_AXI_S2MM] [get_bd_intf_pins axi_mem_raw/S00_AXI]
connect_bd_intf_net [get_bd_intf_pins axi_mem_raw/M00_AXI] \
    [get_bd_intf_pins processing_system7_0/S_AXI_HP0]
connect_bd_intf_net [get_bd_intf_pins vdma_proc/M_AXI_MM2S] [get_bd_intf_pins axi_mem_proc_rd/S00_AXI]
connect_bd_intf_net [get_bd_intf_pins axi_mem_proc_rd/M00_AXI] \
    [get_bd_intf_pins processing_system7_0/S_AXI_HP1]
connect_bd_intf_net [get_bd_intf_pins vdma_proc/M_AXI_S2MM] [get_bd_intf_pins axi_mem_proc_wr/S00_AXI]
connect_bd_intf_net [get_bd_intf_pins axi_mem_proc_wr/M00_AXI] \
    [get_bd_intf_pins processing_system7_0/S_AXI_HP2]
if {$STEREOCAM_BUILD eq "depth"} {
    connect_bd_intf_net [get_bd_intf_pins vdma_depth/M_AXI_S2MM] [get_bd_intf_pins axi_mem_depth/S00_AXI]
    connect_bd_intf_net [get_bd_intf_pins axi_mem_depth/M00_AXI] \
        [get_bd_intf_pins processing_system7_0/S_AXI_HP3]
}

# ---- Interrupts --------------------------------------------------------------------------------------
connect_bd_net [get_bd_pins vdma_raw/s2mm_introut] [get_bd_pins irq_concat/In0]
connect_bd_net [get_bd_pins vdma_proc/mm2s_introut] [get_bd_pins irq_concat/In1]
connect_bd_net [get_bd_pins vdma_proc/s2mm_introut] [get_bd_pins irq_concat/In2]
if {$STEREOCAM_BUILD eq "depth"} {
    connect_bd_net [get_bd_pins vdma_depth/s2mm_introut] [get_bd_pins irq_concat/In3]
    # genlock: vdma_depth's S2MM follows the store vdma_proc's S2MM writes
    connect_bd_net [get_bd_pins vdma_proc/s2mm_frame_ptr_out] [get_bd_pins vdma_depth/s2mm_frame_ptr_in]
}
connect_bd_net [get_bd_pins irq_concat/dout] [get_bd_pins processing_system7_0/IRQ_F2P]

# ---- Clock: FCLK_CLK0 everywhere ---------------------------------------------------------------------
connect_bd_net [get_bd_pins processing_system7_0/FCLK_CLK0] \
    [get_bd_pins processing_system7_0/M_AXI_GP0_ACLK] \
    [get_bd_pins processing_system7_0/S_AXI_HP0_ACLK] \
    [get_bd_pins processing_system7_0/S_AXI_HP1_ACLK] \
    [get_bd_pins processing_system7_0/S_AXI_HP2_ACLK] \
    [get_bd_pins rst_ps7_0/slowest_sync_clk] \
    [get_bd_pins axi_ctrl/ACLK] \
    [get_bd_pins axi_ctrl/S00_ACLK] \
    [get_bd_pins axi_ctrl/M00_ACLK] \
    [get_bd_pins axi_ctrl/M01_ACLK] \
    [get_bd_pins axi_ctrl/M02_ACLK] \
    [get_bd_pins axi_ctrl/M03_ACLK] \
    [get_bd_pins axi_mem_raw/ACLK] \
    [get_bd_pins axi_mem_raw/S00_ACLK] \
    [get_bd_pins axi_mem_raw/M00_ACLK] \
    [get_bd_pins axi_mem_proc_rd/ACLK] \
    [get_bd_pins axi_mem_proc_rd/S00_ACLK] \
    [get_bd_pins axi_mem_proc_rd/M00_ACLK] \
    [get_bd_pins axi_mem_proc_wr/ACLK] \
    [get_bd_pins axi_mem_proc_wr/S00_ACLK] \
    [get_bd_pins axi_mem_proc_wr/M00_ACLK] \
    [get_bd_pins camera_in/aclk] \
    [get_bd_pins camera_split/aclk] \
    [get_bd_pins gate_raw/aclk] \
    [get_bd_pins gate_live/aclk] \
    [get_bd_pins vdma_raw/s_axi_lite_aclk] \
    [get_bd_pins vdma_raw/m_axi_s2mm_aclk] \
    [get_bd_pins vdma_raw/s_axis_s2mm_aclk] \
    [get_bd_pins vdma_proc/s_axi_lite_aclk] \
    [get_bd_pins vdma_proc/m_axi_mm2s_aclk] \
    [get_bd_pins vdma_proc/m_axis_mm2s_aclk] \
    [get_bd_pins vdma_proc/m_axi_s2mm_aclk] \
    [get_bd_pins vdma_proc/s_axis_s2mm_aclk] \
    [get_bd_pins mux/aclk] \
    [get_bd_pins mux/s_axi_ctrl_aclk] \
    [get_bd_pins rectify/aclk]
if {$STEREOCAM_BUILD eq "depth"} {
    # added to FCLK_CLK0's net
    connect_bd_net [get_bd_pins processing_system7_0/FCLK_CLK0] \
        [get_bd_pins processing_system7_0/S_AXI_HP3_ACLK] \
        [get_bd_pins axi_ctrl/M04_ACLK] \
        [get_bd_pins axi_ctrl/M05_ACLK] \
        [get_bd_pins axi_mem_depth/ACLK] \
        [get_bd_pins axi_mem_depth/S00_ACLK] \
        [get_bd_pins axi_mem_depth/M00_ACLK] \
        [get_bd_pins rectified_split/aclk] \
        [get_bd_pins stereo/aclk] \
        [get_bd_pins vdma_depth/s_axi_lite_aclk] \
        [get_bd_pins vdma_depth/m_axi_s2mm_aclk] \
        [get_bd_pins vdma_depth/s_axis_s2mm_aclk]
}

# ---- Resets ------------------------------------------------------------------------------------------
connect_bd_net [get_bd_pins processing_system7_0/FCLK_RESET0_N] [get_bd_pins rst_ps7_0/ext_reset_in]
connect_bd_net [get_bd_pins rst_ps7_0/interconnect_aresetn] \
    [get_bd_pins axi_ctrl/ARESETN] \
    [get_bd_pins axi_mem_raw/ARESETN] \
    [get_bd_pins axi_mem_proc_rd/ARESETN] \
    [get_bd_pins axi_mem_proc_wr/ARESETN]
connect_bd_net [get_bd_pins rst_ps7_0/peripheral_aresetn] \
    [get_bd_pins axi_ctrl/S00_ARESETN] \
    [get_bd_pins axi_ctrl/M00_ARESETN] \
    [get_bd_pins axi_ctrl/M01_ARESETN] \
    [get_bd_pins axi_ctrl/M02_ARESETN] \
    [get_bd_pins axi_ctrl/M03_ARESETN] \
    [get_bd_pins axi_mem_raw/S00_ARESETN] \
    [get_bd_pins axi_mem_raw/M00_ARESETN] \
    [get_bd_pins axi_mem_proc_rd/S00_ARESETN] \
    [get_bd_pins axi_mem_proc_rd/M00_ARESETN] \
    [get_bd_pins axi_mem_proc_wr/S00_ARESETN] \
    [get_bd_pins axi_mem_proc_wr/M00_ARESETN] \
    [get_bd_pins camera_in/aresetn] \
    [get_bd_pins camera_split/aresetn] \
    [get_bd_pins gate_raw/aresetn] \
    [get_bd_pins gate_live/aresetn] \
    [get_bd_pins vdma_raw/axi_resetn] \
    [get_bd_pins vdma_proc/axi_resetn] \
    [get_bd_pins mux/aresetn] \
    [get_bd_pins mux/s_axi_ctrl_aresetn] \
    [get_bd_pins rectify/aresetn]
if {$STEREOCAM_BUILD eq "depth"} {
    # added to interconnect_aresetn's and peripheral_aresetn's nets
    connect_bd_net [get_bd_pins rst_ps7_0/interconnect_aresetn] \
        [get_bd_pins axi_mem_depth/ARESETN]
    connect_bd_net [get_bd_pins rst_ps7_0/peripheral_aresetn] \
        [get_bd_pins axi_ctrl/M04_ARESETN] \
        [get_bd_pins axi_ctrl/M05_ARESETN] \
        [get_bd_pins axi_mem_depth/S00_ARESETN] \
        [get_bd_pins axi_mem_depth/M00_ARESETN] \
        [get_bd_pins rectified_split/aresetn] \
        [get_bd_pins stereo/aresetn] \
        [get_bd_pins vdma_depth/axi_resetn]
}

# ---- Addresses (stereocam/overlays/spec/overlay.py: ADDRESS_MAP, WINDOW_SIZE) ----------------------------------
# The PS7 sees each register window at its base; each VDMA channel sees the 512 MiB of DDR at 0 through
# its own HP port (vdma_raw S2MM HP0, vdma_proc MM2S HP1, vdma_proc S2MM HP2, vdma_depth S2MM HP3).
assign_bd_address -offset 0x43000000 -range 0x00010000 \
    -target_address_space [get_bd_addr_spaces processing_system7_0/Data] \
    [get_bd_addr_segs vdma_raw/S_AXI_LITE/Reg] -force
assign_bd_address -offset 0x43010000 -range 0x00010000 \
    -target_address_space [get_bd_addr_spaces processing_system7_0/Data] \
    [get_bd_addr_segs vdma_proc/S_AXI_LITE/Reg] -force
assign_bd_address -offset 0x43C00000 -range 0x00010000 \
    -target_address_space [get_bd_addr_spaces processing_system7_0/Data] \
    [get_bd_addr_segs rectify/s_axil/reg0] -force
assign_bd_address -offset 0x43C10000 -range 0x00010000 \
    -target_address_space [get_bd_addr_spaces processing_system7_0/Data] \
    [get_bd_addr_segs mux/S_AXI_CTRL/Reg] -force
assign_bd_address -offset 0x00000000 -range 0x20000000 \
    -target_address_space [get_bd_addr_spaces vdma_raw/Data_S2MM] \
    [get_bd_addr_segs processing_system7_0/S_AXI_HP0/HP0_DDR_LOWOCM] -force
assign_bd_address -offset 0x00000000 -range 0x20000000 \
    -target_address_space [get_bd_addr_spaces vdma_proc/Data_MM2S] \
    [get_bd_addr_segs processing_system7_0/S_AXI_HP1/HP1_DDR_LOWOCM] -force
assign_bd_address -offset 0x00000000 -range 0x20000000 \
    -target_address_space [get_bd_addr_spaces vdma_proc/Data_S2MM] \
    [get_bd_addr_segs processing_system7_0/S_AXI_HP2/HP2_DDR_LOWOCM] -force
if {$STEREOCAM_BUILD eq "depth"} {
    assign_bd_address -offset 0x43020000 -range 0x00010000 \
        -target_address_space [get_bd_addr_spaces processing_system7_0/Data] \
        [get_bd_addr_segs vdma_depth/S_AXI_LITE/Reg] -force
    assign_bd_address -offset 0x43C20000 -range 0x00010000 \
        -target_address_space [get_bd_addr_spaces processing_system7_0/Data] \
        [get_bd_addr_segs stereo/s_axil/reg0] -force
    assign_bd_address -offset 0x00000000 -range 0x20000000 \
        -target_address_space [get_bd_addr_spaces vdma_depth/Data_S2MM] \
        [get_bd_addr_segs processing_system7_0/S_AXI_HP3/HP3_DDR_LOWOCM] -force
}
