// Language: Verilog 2005

`include "prelude.vh"

`include "rectify_spec.vh"

/*
 * rectify_core: the stereocam rectify core 2.0 (stereocam/overlays/RECTIFY_CORE.md), top level.
 *
 * AXI4-Lite slave (rc_regs: 12-bit byte address, checked against RECTIFY_MAP.size by
 * tests/overlays/test_overlay_build.py, 32-bit data), AXI4-Stream slave
 * (from the mux) and master (to VDMA "proc" S2MM), 64-bit TDATA, TUSER start of
 * frame, TLAST end of line. The parts:
 *   rc_regs      register block: shadow and active sets, APPLY, flags, frame counter
 *   rc_coord     coordinate engine (steps 1-4), shared by both cameras
 *   rc_datapath  input checking, line buffers, output sequencing, interpolation, output
 * The port names follow Xilinx's conventions so that IP packaging infers the
 * interfaces (aclk, aresetn, s_axil_*, s_axis_*, m_axis_*).
 *
 * Build parameters (read back through MAX_WIDTH, MAX_HEIGHT, LB_ROWS, CAPS.COLOUR):
 * the gray build is COLOUR = 0, the colour build COLOUR = 1 (RECTIFY_CORE.md, "Builds").
 *
 * Latency (clocks, measured in tests/hdl/test_rectify_core_rtl.py): 2 clocks per
 * output beat. The first output beat of a frame leaves 85 clocks after the last
 * beat of input row e(0) = min(LB_DELAY, HEIGHT - 1) is accepted (rc_coord starts
 * then and takes 63 clocks to its first position, the pixel pipeline and FIFO
 * the rest; 22 clocks with BYPASS, which needs no positions; 2 fewer in the gray
 * build): with the input at one beat per clock, WIDTH * (e(0) + 1) + 85 clocks
 * after the start of frame (149 at 64x40, LB_DELAY 0). After the last input beat
 * the rows that waited for it drain at 2 clocks per beat, plus about 70 clocks
 * of pipeline (197 clocks at 64 wide, LB_DELAY 0; 709 with LB_DELAY 4); the next
 * start of frame is accepted once the last output beat has left.
 *
 * Reset: aresetn, active low, synchronous; registered once here into the parts' rst.
 */
module rectify_core #
(
    parameter MAX_WIDTH = 752,
    parameter MAX_HEIGHT = 1024,
    parameter LB_ROWS = 80,
    parameter COLOUR = 1
)
(
    input  wire         aclk,
    input  wire         aresetn,

    /*
     * AXI4-Lite slave
     */
    input  wire [`RC_ADDR_W-1:0] s_axil_awaddr,
    input  wire [2:0]   s_axil_awprot,
    input  wire         s_axil_awvalid,
    output wire         s_axil_awready,
    input  wire [31:0]  s_axil_wdata,
    input  wire [3:0]   s_axil_wstrb,
    input  wire         s_axil_wvalid,
    output wire         s_axil_wready,
    output wire [1:0]   s_axil_bresp,
    output wire         s_axil_bvalid,
    input  wire         s_axil_bready,
    input  wire [`RC_ADDR_W-1:0] s_axil_araddr,
    input  wire [2:0]   s_axil_arprot,
    input  wire         s_axil_arvalid,
    output wire         s_axil_arready,
    output wire [31:0]  s_axil_rdata,
    output wire [1:0]   s_axil_rresp,
    output wire         s_axil_rvalid,
    input  wire         s_axil_rready,

    /*
     * AXI4-Stream slave: both cameras per beat
     */
    input  wire [63:0]  s_axis_tdata,
    input  wire         s_axis_tuser,
    input  wire         s_axis_tlast,
    input  wire         s_axis_tvalid,
    output wire         s_axis_tready,

    /*
     * AXI4-Stream master
     */
    output wire [63:0]  m_axis_tdata,
    output wire         m_axis_tuser,
    output wire         m_axis_tlast,
    output wire         m_axis_tvalid,
    input  wire         m_axis_tready
);

localparam NP = `RC_NPARAMS;
localparam PW = `RC_POS_W;

// ~4,000 loads: Vivado's synthesis replicates it so that no copy drives more than 64 (the timing
// estimate, stereocam hw timing, assumes the same)
(* max_fanout = 64 *) reg rst_reg = 1'b1;

always @(posedge aclk) begin
    rst_reg <= !aresetn;
end

/*
 * Register block
 */
wire             idle;
wire             frame_done;
wire             set_lb_overflow;
wire             set_size_error;
wire             busy;
wire             applied;
wire [NP*64-1:0] act_l;
wire [NP*64-1:0] act_r;
wire [15:0]      act_width;
wire [15:0]      act_height;
wire [15:0]      act_lb_delay;
wire             ctl_enable;
wire             ctl_bypass;
wire             ctl_gray;
wire             ctl_debug_line;
wire [15:0]      debug_row;
wire             apply_pending;

rc_regs #(
    .MAX_WIDTH(MAX_WIDTH),
    .MAX_HEIGHT(MAX_HEIGHT),
    .LB_ROWS(LB_ROWS),
    .COLOUR(COLOUR)
)
regs_inst (
    .clk(aclk),
    .rst(rst_reg),
    .s_axil_awaddr(s_axil_awaddr),
    .s_axil_awvalid(s_axil_awvalid),
    .s_axil_awready(s_axil_awready),
    .s_axil_wdata(s_axil_wdata),
    .s_axil_wstrb(s_axil_wstrb),
    .s_axil_wvalid(s_axil_wvalid),
    .s_axil_wready(s_axil_wready),
    .s_axil_bresp(s_axil_bresp),
    .s_axil_bvalid(s_axil_bvalid),
    .s_axil_bready(s_axil_bready),
    .s_axil_araddr(s_axil_araddr),
    .s_axil_arvalid(s_axil_arvalid),
    .s_axil_arready(s_axil_arready),
    .s_axil_rdata(s_axil_rdata),
    .s_axil_rresp(s_axil_rresp),
    .s_axil_rvalid(s_axil_rvalid),
    .s_axil_rready(s_axil_rready),
    .idle(idle),
    .frame_done(frame_done),
    .set_lb_overflow(set_lb_overflow),
    .set_size_error(set_size_error),
    .busy(busy),
    .applied(applied),
    .act_l(act_l),
    .act_r(act_r),
    .act_width(act_width),
    .act_height(act_height),
    .act_lb_delay(act_lb_delay),
    .ctl_enable(ctl_enable),
    .ctl_bypass(ctl_bypass),
    .ctl_gray(ctl_gray),
    .ctl_debug_line(ctl_debug_line),
    .debug_row(debug_row),
    .apply_pending(apply_pending)
);

/*
 * Coordinate engine
 */
wire                 coord_start;
wire [15:0]          coord_width;
wire [15:0]          coord_height;
wire                 pos_valid;
wire                 pos_ready;
wire signed [PW-1:0] pos_iu_l;
wire signed [PW-1:0] pos_iv_l;
wire signed [PW-1:0] pos_iu_r;
wire signed [PW-1:0] pos_iv_r;
wire                 pos_ok_l;
wire                 pos_ok_r;

rc_coord coord_inst (
    .clk(aclk),
    .rst(rst_reg),
    .start(coord_start),
    .par_l(act_l),
    .par_r(act_r),
    .width(coord_width),
    .height(coord_height),
    .out_valid(pos_valid),
    .out_ready(pos_ready),
    .iu_l(pos_iu_l),
    .iv_l(pos_iv_l),
    .iu_r(pos_iu_r),
    .iv_r(pos_iv_r),
    .ok_l(pos_ok_l),
    .ok_r(pos_ok_r)
);

/*
 * Datapath
 */
rc_datapath #(
    .MAX_WIDTH(MAX_WIDTH),
    .MAX_HEIGHT(MAX_HEIGHT),
    .LB_ROWS(LB_ROWS),
    .COLOUR(COLOUR)
)
datapath_inst (
    .clk(aclk),
    .rst(rst_reg),
    .s_axis_tdata(s_axis_tdata),
    .s_axis_tvalid(s_axis_tvalid),
    .s_axis_tready(s_axis_tready),
    .s_axis_tlast(s_axis_tlast),
    .s_axis_tuser(s_axis_tuser),
    .m_axis_tdata(m_axis_tdata),
    .m_axis_tvalid(m_axis_tvalid),
    .m_axis_tready(m_axis_tready),
    .m_axis_tlast(m_axis_tlast),
    .m_axis_tuser(m_axis_tuser),
    .applied(applied),
    .act_width(act_width),
    .act_height(act_height),
    .act_lb_delay(act_lb_delay),
    .ctl_enable(ctl_enable),
    .ctl_bypass(ctl_bypass),
    .ctl_gray(ctl_gray),
    .ctl_debug_line(ctl_debug_line),
    .debug_row(debug_row),
    .apply_pending(apply_pending),
    .idle(idle),
    .frame_done(frame_done),
    .set_lb_overflow(set_lb_overflow),
    .set_size_error(set_size_error),
    .busy(busy),
    .coord_start(coord_start),
    .coord_width(coord_width),
    .coord_height(coord_height),
    .pos_valid(pos_valid),
    .pos_ready(pos_ready),
    .pos_iu_l(pos_iu_l),
    .pos_iv_l(pos_iv_l),
    .pos_ok_l(pos_ok_l),
    .pos_iu_r(pos_iu_r),
    .pos_iv_r(pos_iv_r),
    .pos_ok_r(pos_ok_r)
);

// AXI4-Lite protection types carry nothing here (they exist for the interface's inference)
// verilator lint_off UNUSEDSIGNAL
wire unused_ok = &{1'b0, s_axil_awprot, s_axil_arprot};
// verilator lint_on UNUSEDSIGNAL

endmodule

`resetall
