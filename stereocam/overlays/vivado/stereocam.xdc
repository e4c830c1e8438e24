# stereocam.xdc: the timing constraints of the camera inputs (the block design's external ports).
#
# The pins are placed by the board's pin map, not here (stereocam/overlays/vivado/pins/<board>.pins,
# which build.tcl reads and writes as the build's own pins.xdc): this file holds what does not
# depend on the board's wiring, and build.tcl always adds it.

# ---- Clocks ------------------------------------------------------------------------------------
# The MT9V034's pixel clock follows its SYSCLK: 26.6 MHz on the reference design
# (stereocam/overlays/spec/mt9v034.py: PIXEL_CLOCK_HZ), at most 27 MHz (the sensor's limit), so both are
# constrained at 27 MHz. camera_in carries their data into FCLK_CLK0 (clk_fpga_0, created by the
# PS7's own constraints) through its clock-domain crossings; the clocks are unrelated to each other.
create_clock -period 37.037 -name cam0_pclk [get_ports cam0_pclk]
create_clock -period 37.037 -name cam1_pclk [get_ports cam1_pclk]

# ---- Clock-domain crossings (stereocam/overlays/rtl/camera/README.md, "Clock domains and crossings") ----
# Every crossing of camera_in goes through a ci_sync (two flops, ASYNC_REG): a line FIFO's write
# pointer (gray, one step per pixel clock), its read pointer's handshake (a held value beside req/ack),
# the frame tag (gray), FRAME_VALID and the receivers' reset. No asynchronous clock groups: each path
# between the domains is bounded to one FCLK_CLK0 period (10 ns at 100 MHz, settings.tcl; less than
# either destination's period), its data path alone, and the multi-bit buses' skew to the same, so a
# destination sees every bit of a change within one of its clocks (what tests/hdl/test_camera_in_skew.py
# simulates). Change the 10.000s with STEREOCAM_FCLK0_MHZ.
set_max_delay -datapath_only -from [get_clocks cam0_pclk] -to [get_clocks clk_fpga_0] 10.000
set_max_delay -datapath_only -from [get_clocks clk_fpga_0] -to [get_clocks cam0_pclk] 10.000
set_max_delay -datapath_only -from [get_clocks cam1_pclk] -to [get_clocks clk_fpga_0] 10.000
set_max_delay -datapath_only -from [get_clocks clk_fpga_0] -to [get_clocks cam1_pclk] 10.000
# the gray write pointers into FCLK_CLK0
set_bus_skew -from [get_cells -hier -filter {NAME =~ */fifo0_inst/wgray_reg_reg[*]}] \
    -to [get_cells -hier -filter {NAME =~ */fifo0_inst/wsync_inst/meta_reg_reg[*]}] 10.000
set_bus_skew -from [get_cells -hier -filter {NAME =~ */fifo1_inst/wgray_reg_reg[*]}] \
    -to [get_cells -hier -filter {NAME =~ */fifo1_inst/wsync_inst/meta_reg_reg[*]}] 10.000
# the read pointers' held values into the pixel clocks
set_bus_skew -from [get_cells -hier -filter {NAME =~ */fifo0_inst/rhold_reg_reg[*]}] \
    -to [get_cells -hier -filter {NAME =~ */fifo0_inst/rsync_inst/meta_reg_reg[*]}] 10.000
set_bus_skew -from [get_cells -hier -filter {NAME =~ */fifo1_inst/rhold_reg_reg[*]}] \
    -to [get_cells -hier -filter {NAME =~ */fifo1_inst/rsync_inst/meta_reg_reg[*]}] 10.000
# the gray frame tag into the pixel clocks
set_bus_skew -from [get_cells -hier -filter {NAME =~ */camera_in/*tag_gray_reg_reg[*]}] \
    -to [get_cells -hier -filter {NAME =~ */rx0_inst/tag_sync_inst/meta_reg_reg[*]}] 10.000
set_bus_skew -from [get_cells -hier -filter {NAME =~ */camera_in/*tag_gray_reg_reg[*]}] \
    -to [get_cells -hier -filter {NAME =~ */rx1_inst/tag_sync_inst/meta_reg_reg[*]}] 10.000

# Input delays of DOUT, LINE_VALID and FRAME_VALID relative to PIXCLK come from the MT9V034 data
# sheet's output timing and the board's trace lengths; fill them in with the pins, e.g.:
# set_input_delay -clock cam0_pclk -max <ns> [get_ports {cam0_data[*] cam0_line_valid cam0_frame_valid}]
# set_input_delay -clock cam0_pclk -min <ns> [get_ports {cam0_data[*] cam0_line_valid cam0_frame_valid}]
# set_input_delay -clock cam1_pclk -max <ns> [get_ports {cam1_data[*] cam1_line_valid cam1_frame_valid}]
# set_input_delay -clock cam1_pclk -min <ns> [get_ports {cam1_data[*] cam1_line_valid cam1_frame_valid}]
