// Language: Verilog 2005

`include "prelude.vh"

`include "stereo_spec.vh"

/*
 * stereo_core: the stereocam stereo core 1.0 (stereocam/overlays/STEREO_CORE.md), top level.
 *
 * AXI4-Lite slave (sc_regs, SC_ADDR_W-bit byte address, 32-bit data); AXI4-Stream slave of the
 * rectify core's 64-bit pixels (the gray bytes are read), master of 32-bit disparity beats, TUSER
 * start of frame, TLAST end of row. The parts, paced in lockstep by sc_sched (slots of 4 clocks,
 * sweeps of a frame):
 *   sc_input   stream in, the line buffer's write port, rows counted
 *   sc_front   census, costs, the three paths: the sums S, one group of PARALLEL a clock
 *   sc_winners the left winners (winner, runner-up, sub-pixel, uniqueness, confidence: a record
 *              per pixel) and the right image's (diagonal minimum)
 *   sc_passes  validity and the left-right check (phase B), the 3x3 median and the output
 *              beat (phase C)
 * with three RAMs banked by row mod 3 (records, right winners, and inside sc_passes the checked
 * codes) and an output FIFO
 * whose room the scheduler checks before each slot.
 * Build parameters (read back through MAX_WIDTH, MAX_HEIGHT, MAX_DISP, PARALLEL): the `depth`
 * build is 752 / 1024 / 128 / 32; MAX_DISP must be 4 PARALLEL.
 * Reset: aresetn, active low, synchronous; registered once here.
 */
module stereo_core #
(
    parameter MAX_WIDTH = `SC_BUILD_DEPTH_MAX_WIDTH,
    parameter MAX_HEIGHT = `SC_BUILD_DEPTH_MAX_HEIGHT,
    parameter MAX_DISP = `SC_BUILD_DEPTH_MAX_DISP,
    parameter PARALLEL = `SC_BUILD_DEPTH_PARALLEL
)
(
    input  wire         aclk,
    input  wire         aresetn,

    input  wire [`SC_ADDR_W-1:0] s_axil_awaddr,
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
    input  wire [`SC_ADDR_W-1:0] s_axil_araddr,
    input  wire [2:0]   s_axil_arprot,
    input  wire         s_axil_arvalid,
    output wire         s_axil_arready,
    output wire [31:0]  s_axil_rdata,
    output wire [1:0]   s_axil_rresp,
    output wire         s_axil_rvalid,
    input  wire         s_axil_rready,

    input  wire [63:0]  s_axis_tdata,
    input  wire         s_axis_tuser,
    input  wire         s_axis_tlast,
    input  wire         s_axis_tvalid,
    output wire         s_axis_tready,

    output wire [31:0]  m_axis_tdata,
    output wire         m_axis_tuser,
    output wire         m_axis_tlast,
    output wire         m_axis_tvalid,
    input  wire         m_axis_tready
);

localparam RAM_DEPTH = 3 * MAX_WIDTH;
localparam AW = $clog2(RAM_DEPTH);
localparam OUT_DEPTH = 32;
localparam PRE = 16;
localparam LAG = 4;

// parameter checks: a build that breaks one fails to elaborate, naming the rule (the packaged IP's
// user parameters allow each value alone; this is the rule between them)
generate
    // verilator lint_off GENUNNAMED
    if (MAX_DISP != 4 * PARALLEL) stereo_core_parameter_MAX_DISP_must_be_4_x_PARALLEL max_disp_not_4_slots();
    // verilator lint_on GENUNNAMED
endgenerate

reg rst = 1'b1;
always @(posedge aclk) rst <= !aresetn;

`include "sc_bank.vh"

// ---- registers
wire        enable, apply_pending, idle, busy, frame_done, size_error;
wire [10:0] width, height;
wire [7:0]  num_disp, p1, p2, p2_edge, edge_thresh, uniqueness;
wire [3:0]  lr_tol;
wire        lr_check, subpixel, median;
reg         frame_out = 1'b0;  // the frame's last beat left

sc_regs #(
    .MAX_WIDTH(MAX_WIDTH), .MAX_HEIGHT(MAX_HEIGHT), .MAX_DISP(MAX_DISP), .PARALLEL(PARALLEL)
) regs_inst (
    .clk(aclk), .rst(rst),
    .s_axil_awaddr(s_axil_awaddr), .s_axil_awvalid(s_axil_awvalid), .s_axil_awready(s_axil_awready),
    .s_axil_wdata(s_axil_wdata), .s_axil_wstrb(s_axil_wstrb), .s_axil_wvalid(s_axil_wvalid),
    .s_axil_wready(s_axil_wready), .s_axil_bresp(s_axil_bresp), .s_axil_bvalid(s_axil_bvalid),
    .s_axil_bready(s_axil_bready), .s_axil_araddr(s_axil_araddr), .s_axil_arvalid(s_axil_arvalid),
    .s_axil_arready(s_axil_arready), .s_axil_rdata(s_axil_rdata), .s_axil_rresp(s_axil_rresp),
    .s_axil_rvalid(s_axil_rvalid), .s_axil_rready(s_axil_rready),
    .idle(idle), .frame_done(frame_out), .set_size_error(size_error), .busy(busy),
    .enable(enable), .apply_pending_out(apply_pending),
    .width(width), .height(height), .num_disp(num_disp), .p1(p1), .p2(p2), .p2_edge(p2_edge),
    .edge_thresh(edge_thresh), .uniqueness(uniqueness), .lr_tol(lr_tol),
    .lr_check(lr_check), .subpixel(subpixel), .median(median)
);

// ---- scheduler and input
wire        run, accept_frame, frame_begin, out_room;
wire [1:0]  phase;
wire signed [11:0] row, col;
wire [1:0]  row_bank;
wire [10:0] row_limit, rows_in;
wire        lb_we;
wire [10:0] lb_col, lb_row;
wire [15:0] lb_data;

sc_sched #(.MAX_DISP(MAX_DISP), .PRE(PRE)) sched_inst (
    .clk(aclk), .rst(rst), .enable(enable), .width(width), .height(height), .rows_in(rows_in),
    .frame_begin(frame_begin), .out_room(out_room), .hold(apply_pending), .idle(idle),
    .accept_frame(accept_frame), .run(run), .phase(phase), .row(row), .col(col),
    .row_bank(row_bank), .row_limit(row_limit), .busy(busy), .frame_done(frame_done)
);

sc_input input_inst (
    .clk(aclk), .rst(rst),
    .s_tdata(s_axis_tdata), .s_tuser(s_axis_tuser), .s_tlast(s_axis_tlast),
    .s_tvalid(s_axis_tvalid), .s_tready(s_axis_tready),
    .enable(enable), .width(width), .height(height), .accept_frame(accept_frame),
    .frame_begin(frame_begin), .row_limit(row_limit), .rows_in(rows_in),
    .lb_we(lb_we), .lb_col(lb_col), .lb_row(lb_row), .lb_data(lb_data), .size_error(size_error)
);

// ---- front: the sums
wire                          f_valid;
wire [1:0]                    f_group;
wire [10:0]                   f_x, f_y;
wire [PARALLEL*`SC_SUM_W-1:0] f_sum;

sc_front #(.MAX_WIDTH(MAX_WIDTH), .MAX_DISP(MAX_DISP), .PARALLEL(PARALLEL)) front_inst (
    .clk(aclk), .rst(rst),
    .lb_we(lb_we), .lb_col(lb_col), .lb_row(lb_row), .lb_data(lb_data),
    .width(width), .height(height), .num_disp(num_disp),
    .p1(p1), .p2(p2), .p2_edge(p2_edge), .edge_thresh(edge_thresh),
    .run(run), .phase(phase), .row(row), .col(col),
    .m_valid(f_valid), .m_group(f_group), .m_x(f_x), .m_y(f_y), .m_sum(f_sum)
);

// ---- winners and records
wire        r_valid, r_unique, r_border;
wire [10:0] r_x, r_y, r_code;
wire [6:0]  r_d1;
wire [7:0]  r_conf;

wire          dw_en;
wire [AW-1:0] dw_addr;
wire [6:0]    dw_d;
sc_winners #(.MAX_WIDTH(MAX_WIDTH), .MAX_DISP(MAX_DISP), .PARALLEL(PARALLEL), .AW(AW)) winners_inst (
    .clk(aclk), .rst(rst), .width(width), .num_disp(num_disp), .uniqueness(uniqueness),
    .subpixel(subpixel),
    .s_valid(f_valid), .s_group(f_group), .s_x(f_x), .s_y(f_y), .s_sum(f_sum),
    .r_valid(r_valid), .r_x(r_x), .r_y(r_y), .r_d1(r_d1), .r_code(r_code), .r_conf(r_conf),
    .r_unique(r_unique), .r_border(r_border),
    .w_en(dw_en), .w_addr(dw_addr), .w_d(dw_d)
);

wire          rec_re;
wire [AW-1:0] rec_raddr;
wire [27:0]   rec_rdata;
// A record is written two clocks after it leaves the winners: its row's bank first, then the
// address (from r_y through bank_base and the add into the RAM was a path over the period, and
// the bank and the add in one clock still too long); phase B reads it two sweeps later.
reg           rec_we0 = 1'b0, rec_we = 1'b0;
reg [AW-1:0]  rec_base0;
reg [10:0]    rec_x0;
reg [27:0]    rec_wdata0;
reg [AW-1:0]  rec_waddr;
reg [27:0]    rec_wdata;
always @(posedge aclk) begin
    rec_we0 <= r_valid && !rst;
    rec_base0 <= bank_base(r_y);
    rec_x0 <= r_x;
    rec_wdata0 <= {r_border, r_unique, r_conf, r_code, r_d1};
    rec_we <= rec_we0 && !rst;
    rec_waddr <= rec_base0 + rec_x0;
    rec_wdata <= rec_wdata0;
end
// (in 9-bit slices, a block RAM each as 4K x 9: one deep, no LUTs choosing between blocks: rc_ram)
rc_ram #(.WIDTH(28), .DEPTH(RAM_DEPTH), .AW(AW), .SLICE(9)) rec_ram (
    .clk(aclk), .we(rec_we), .waddr(rec_waddr), .wdata(rec_wdata),
    .re(rec_re), .raddr(rec_raddr), .rdata(rec_rdata)
);

wire          dr_re;
wire [AW-1:0] dr_raddr;
wire [6:0]    dr_rdata;
rc_ram #(.WIDTH(7), .DEPTH(RAM_DEPTH), .AW(AW)) dr_ram (
    .clk(aclk), .we(dw_en), .waddr(dw_addr), .wdata(dw_d),
    .re(dr_re), .raddr(dr_raddr), .rdata(dr_rdata)
);

// ---- phases B and C: validity and the left-right check, the median, the beats
wire        o_valid, o_user, o_last, o_eof;
wire [31:0] o_data;
sc_passes #(.MAX_WIDTH(MAX_WIDTH), .AW(AW), .LAG(LAG)) passes_inst (
    .clk(aclk), .rst(rst), .width(width), .height(height), .lr_check(lr_check), .lr_tol(lr_tol),
    .median(median), .frame_begin(frame_begin), .run(run), .phase(phase), .row(row), .col(col),
    .row_bank(row_bank), .rec_re(rec_re), .rec_raddr(rec_raddr), .rec_rdata(rec_rdata),
    .dr_re(dr_re), .dr_raddr(dr_raddr), .dr_rdata(dr_rdata),
    .o_valid(o_valid), .o_data(o_data), .o_user(o_user), .o_last(o_last), .o_eof(o_eof)
);

wire [$clog2(OUT_DEPTH+1)-1:0] out_count;
wire        out_eof;
rc_fifo #(.WIDTH(35), .DEPTH(OUT_DEPTH), .SHOW_AHEAD(1), .OUTPUT_REG(1)) out_fifo (
    .clk(aclk), .rst(rst),
    .s_data({o_eof, o_last, o_user, o_data}), .s_valid(o_valid), .s_ready(),
    .m_data({out_eof, m_axis_tlast, m_axis_tuser, m_axis_tdata}), .m_valid(m_axis_tvalid),
    .m_ready(m_axis_tready), .count(out_count)
);
assign out_room = out_count <= OUT_DEPTH - 14;  // 13 beats in flight, 1 for sc_sched's registered test

always @(posedge aclk) begin
    frame_out <= !rst && m_axis_tvalid && m_axis_tready && out_eof;
end

endmodule

`resetall
