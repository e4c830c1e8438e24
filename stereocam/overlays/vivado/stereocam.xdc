# stereocam.xdc: the timing constraints of the camera inputs (the block design's external ports).
#
# The pins are placed by the board's pin map, not here (stereocam/overlays/vivado/pins/<board>.pins,
# which build.tcl reads and writes as the build's own pins.xdc): this file holds what does not
# depend on the board's wiring, and build.tcl always adds it.

# ---- Clocks ------------------------------------------------------------------------------------
# The MT9V034's pixel clock follows its SYSCLK: 26.6 MHz on the reference design
# (stereocam/overlays/spec/mt9v034.py: PIXEL_CLOCK_HZ), at most 27 MHz (the sensor's limit), so both are
# constrained at 27 MHz. camera_in carries their data into FCLK_CLK0 (clk_fpga_0, created by the
# PS7's own constraints) through its clock-domain crossing; the clocks are unrelated to each other.
create_clock -period 37.037 -name cam0_pclk [get_ports cam0_pclk]
create_clock -period 37.037 -name cam1_pclk [get_ports cam1_pclk]
set_clock_groups -asynchronous -group [get_clocks cam0_pclk] -group [get_clocks cam1_pclk] \
    -group [get_clocks clk_fpga_0]

# Input delays of DOUT, LINE_VALID and FRAME_VALID relative to PIXCLK come from the MT9V034 data
# sheet's output timing and the board's trace lengths; fill them in with the pins, e.g.:
# set_input_delay -clock cam0_pclk -max <ns> [get_ports {cam0_data[*] cam0_line_valid cam0_frame_valid}]
# set_input_delay -clock cam0_pclk -min <ns> [get_ports {cam0_data[*] cam0_line_valid cam0_frame_valid}]
# set_input_delay -clock cam1_pclk -max <ns> [get_ports {cam1_data[*] cam1_line_valid cam1_frame_valid}]
# set_input_delay -clock cam1_pclk -min <ns> [get_ports {cam1_data[*] cam1_line_valid cam1_frame_valid}]
