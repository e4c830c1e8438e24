// Language: Verilog 2005

`resetall
`timescale 1ns / 1ps
`default_nettype none

`include "stereo_spec.vh"

/*
 * sc_lr: phase B of the stereo core (STEREO_CORE.md, step 7): each pixel's validity, in the
 * spec's order (matched outside the right image; not unique; with LR_CHECK, the right winner at
 * x - d1 more than LR_TOL away), and its code and confidence as they go to the median.
 *
 * Lockstep: `run` enables this clock; a slot is 4 run clocks (`phase`); `row`, `col` are phase B's
 * pixel of the slot (the scheduler's sweep row - 2). Phase 0 reads the pixel's record, phase 2
 * reads the right winner at x - d1, and phase 0 of the next slot writes the checked code.
 * The RAMs: records and right winners (written by sc_select and sc_diag), the codes (read by
 * sc_median), each banked by row mod 3 at MAX_WIDTH words a bank; reads take 2 run clocks.
 * Reset: synchronous, active high.
 */
module sc_lr #
(
    parameter MAX_WIDTH = 752,
    parameter AW = $clog2(3 * MAX_WIDTH)
)
(
    input  wire               clk,
    input  wire               rst,

    input  wire [10:0]        width,
    input  wire [10:0]        height,
    input  wire               lr_check,
    input  wire [3:0]         lr_tol,

    input  wire               run,
    input  wire [1:0]         phase,
    input  wire signed [11:0] row,
    input  wire signed [11:0] col,

    output wire               rec_re,
    output wire [AW-1:0]      rec_raddr,
    input  wire [27:0]        rec_rdata,   // {border, unique, conf[7:0], code[10:0], d1[6:0]}
    output wire               dr_re,
    output wire [AW-1:0]      dr_raddr,
    input  wire [6:0]         dr_rdata,

    output reg                code_we = 1'b0,
    output reg  [AW-1:0]      code_waddr,
    output reg  [26:0]        code_wdata   // {reason[2:0], conf[7:0], code[15:0]}
);

`include "sc_bank.vh"

wire real_now = row >= 0 && row < $signed({1'b0, height}) && col >= 0 && col < $signed({1'b0, width});

// phase 0: the record
reg          a_real = 1'b0;
reg [10:0]   a_x;
reg [AW-1:0] a_base;
assign rec_re = run && phase == 2'd0 && real_now;
assign rec_raddr = bank_base(row[10:0]) + col[10:0];
always @(posedge clk) begin
    if (rst) begin
        a_real <= 1'b0;
    end else if (run && phase == 2'd0) begin
        a_real <= real_now;
        a_x <= col[10:0];
        a_base <= bank_base(row[10:0]);
    end
end

// phase 2: the record arrives; the right winner's read
wire [6:0]   rec_d1 = rec_rdata[6:0];
wire [10:0]  rec_code = rec_rdata[17:7];
wire [7:0]   rec_conf = rec_rdata[25:18];
wire         rec_unique = rec_rdata[26];
wire         rec_border = rec_rdata[27];
reg          b_real = 1'b0;
reg [10:0]   b_x;
reg [AW-1:0] b_base;
reg [6:0]    b_d1;
reg [10:0]   b_code;
reg [7:0]    b_conf;
reg          b_unique, b_border;
assign dr_re = run && phase == 2'd2 && a_real && !rec_border;
assign dr_raddr = a_base + (a_x - rec_d1);
always @(posedge clk) begin
    if (rst) begin
        b_real <= 1'b0;
    end else if (run && phase == 2'd2) begin
        b_real <= a_real;
        b_x <= a_x;
        b_base <= a_base;
        b_d1 <= rec_d1;
        b_code <= rec_code;
        b_conf <= rec_conf;
        b_unique <= rec_unique;
        b_border <= rec_border;
    end
end

// phase 0 of the next slot: decide and write
wire [7:0] gap = (b_d1 > dr_rdata) ? b_d1 - dr_rdata : dr_rdata - b_d1;
reg  [2:0] reason;
always @* begin
    if (b_border) reason = `SC_REASON_BORDER;
    else if (!b_unique) reason = `SC_REASON_UNIQUENESS;
    else if (lr_check && gap > lr_tol) reason = `SC_REASON_LR;
    else reason = `SC_REASON_VALID;
end
always @(posedge clk) begin
    code_we <= 1'b0;
    if (!rst && run && phase == 2'd0 && b_real) begin
        code_we <= 1'b1;
        code_waddr <= b_base + b_x;
        code_wdata <= (reason == `SC_REASON_VALID) ? {reason, b_conf, 5'b0, b_code}
                                                   : {reason, 8'd0, 16'd`SC_INVALID};
    end
end

endmodule

`resetall
