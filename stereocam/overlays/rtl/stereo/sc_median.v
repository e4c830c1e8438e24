// Language: Verilog 2005

`resetall
`timescale 1ns / 1ps
`default_nettype none

`include "stereo_spec.vh"

/*
 * sc_median: phase C of the stereo core (STEREO_CORE.md, step 8) and the output beat.
 *
 * Lockstep: `run` enables this clock; a slot is 4 run clocks (`phase`); `row` is the scheduler's
 * sweep row - 3 and `x` = the slot's column - LAG (phase B writes the row below, one slot behind
 * its own column: a lag of 4 columns leaves 2 slots between that write and the read here).
 * Each slot reads column x + 1 of rows row - 1, row, row + 1 (phases 0, 1, 2; 2 run clocks each),
 * shifts them into a 3x3 window at phase 1 of the next slot and hands the window (centre x of
 * the previous slot) to the median network, which runs free in 5 stages (two compare levels
 * each) and writes the beat.
 * Out: `o_valid` one clock a pixel: o_data {5'b0, reason, conf, code}, o_user (first pixel of a
 * frame), o_last (end of a row), o_eof (the frame's last beat).
 * `frame_begin` (the first beat of a frame taken, while no slot runs) forgets the last slot's centre.
 * Reset: synchronous, active high.
 */
module sc_median #
(
    parameter MAX_WIDTH = 752,
    parameter AW = $clog2(3 * MAX_WIDTH)
)
(
    input  wire               clk,
    input  wire               rst,

    input  wire [10:0]        width,
    input  wire [10:0]        height,
    input  wire               median,
    input  wire               frame_begin,  // a frame's first beat is taken (between frames)

    input  wire               run,
    input  wire [1:0]         phase,
    input  wire signed [11:0] row,
    input  wire signed [11:0] x,

    output wire               code_re,
    output wire [AW-1:0]      code_raddr,
    input  wire [26:0]        code_rdata,

    output reg                o_valid = 1'b0,
    output reg  [31:0]        o_data,
    output reg                o_user,
    output reg                o_last,
    output reg                o_eof
);

localparam CW = 27;

`include "sc_bank.vh"

// ---- reads: column x + 1 of rows row - 1 + phase (phases 0..2)
wire signed [11:0] rrow = row - 12'sd1 + $signed({10'b0, phase});
wire signed [11:0] rcol = x + 12'sd1;
wire        row_in = rrow >= 0 && rrow < $signed({1'b0, height});
wire        col_in = rcol >= 0 && rcol < $signed({1'b0, width});
assign code_re = run && phase != 2'd3 && row_in && col_in;
assign code_raddr = bank_base(rrow[10:0]) + rcol[10:0];

// what each read brings, 2 run clocks later: phases 2, 3 and the next slot's 0
reg [1:0] q_in;       // [0]: read 1 run clock ago, [1]: 2 run clocks ago
reg [1:0] q_slot0, q_slot1;  // their window row (0..2)
reg       q_ok0, q_ok1;      // inside the image
always @(posedge clk) begin
    if (rst) begin
        q_in <= 2'b00;
    end else if (run) begin
        q_in <= {q_in[0], phase != 2'd3};
        q_slot1 <= q_slot0;
        q_ok1 <= q_ok0;
        q_slot0 <= phase;
        q_ok0 <= row_in && col_in;
    end
end
reg [CW-1:0] newc [0:2];
reg          newv [0:2];
always @(posedge clk) begin
    if (run && q_in[1]) begin
        newc[q_slot1] <= code_rdata;
        newv[q_slot1] <= q_ok1;
    end
end

// ---- the window, shifted at phase 1 (all three of the column are in by then)
integer ri3, ri4, ri5, ci4;
reg [CW-1:0] win [0:2][0:2];  // [row][column]
reg          wv  [0:2][0:2];
reg signed [11:0] prev_x = -12'sd1, cur_x = -12'sd1, prev_row = -12'sd1, cur_row = -12'sd1;
reg          go = 1'b0;       // the window now holds a centre to filter
always @(posedge clk) begin
    go <= 1'b0;
    if (rst) begin
        go <= 1'b0;
        prev_x <= -12'sd1;
        prev_row <= -12'sd1;
    end else if (run && phase == 2'd1) begin
        for (ri3 = 0; ri3 < 3; ri3 = ri3 + 1) begin
            win[ri3][0] <= win[ri3][1];
            wv[ri3][0] <= wv[ri3][1];
            win[ri3][1] <= win[ri3][2];
            wv[ri3][1] <= wv[ri3][2];
            win[ri3][2] <= newc[ri3];
            wv[ri3][2] <= newv[ri3];
        end
        go <= 1'b1;
        cur_x <= prev_x;
        cur_row <= prev_row;
    end
    if (run && phase == 2'd3) begin
        prev_x <= x;    // this slot's column arrives by the next slot's phase 1: centre x
        prev_row <= row;
    end
    // The frame's first slot hands on the centre of the slot before it: none. Without this it
    // was the previous frame's last (a column and row outside that frame, which a wider or
    // taller frame takes for one of its own: a beat before the TUSER beat).
    if (frame_begin) begin
        prev_x <= -12'sd1;
        prev_row <= -12'sd1;
    end
end

// ---- the nine codes, outside ones as the centre; then the median network (Devillard's opt_med9)
wire [15:0] centre = win[1][1][15:0];
reg  [15:0] p [0:8];
always @* begin
    for (ri4 = 0; ri4 < 3; ri4 = ri4 + 1)
        for (ci4 = 0; ci4 < 3; ci4 = ci4 + 1)
            p[ri4*3+ci4] = wv[ri4][ci4] ? win[ri4][ci4][15:0] : centre;
end

function [31:0] srt;  // {min, max}
    input [15:0] a;
    input [15:0] b;
    begin
        srt = (b < a) ? {b, a} : {a, b};
    end
endfunction

// pipeline registers: s1..s5 hold the nine values (or what is left of them) and the centre's data
reg [15:0] s1 [0:8];
reg [15:0] s2 [0:8];
reg [15:0] s3 [0:8];
reg [15:0] s4 [0:8];
reg [15:0] m5;
reg [CW-1:0] c1, c2, c3, c4, c5;
reg        v1 = 1'b0, v2 = 1'b0, v3 = 1'b0, v4 = 1'b0, v5 = 1'b0;
reg signed [11:0] x1 = -12'sd1, x2 = -12'sd1, x3 = -12'sd1, x4 = -12'sd1, x5 = -12'sd1;
reg signed [11:0] y1 = -12'sd1, y2 = -12'sd1, y3 = -12'sd1, y4 = -12'sd1, y5 = -12'sd1;
reg [15:0] t [0:8];
reg [31:0] o;
always @(posedge clk) begin
    // stage 1: sort(1,2) sort(4,5) sort(7,8); sort(0,1) sort(3,4) sort(6,7)
    for (ri5 = 0; ri5 < 9; ri5 = ri5 + 1) t[ri5] = p[ri5];
    o = srt(t[1], t[2]); t[1] = o[31:16]; t[2] = o[15:0];
    o = srt(t[4], t[5]); t[4] = o[31:16]; t[5] = o[15:0];
    o = srt(t[7], t[8]); t[7] = o[31:16]; t[8] = o[15:0];
    o = srt(t[0], t[1]); t[0] = o[31:16]; t[1] = o[15:0];
    o = srt(t[3], t[4]); t[3] = o[31:16]; t[4] = o[15:0];
    o = srt(t[6], t[7]); t[6] = o[31:16]; t[7] = o[15:0];
    for (ri5 = 0; ri5 < 9; ri5 = ri5 + 1) s1[ri5] <= t[ri5];
    // stage 2: sort(1,2) sort(4,5) sort(7,8); p3 = max(0,3); p5 = min(5,8); (p6 kept)
    for (ri5 = 0; ri5 < 9; ri5 = ri5 + 1) t[ri5] = s1[ri5];
    o = srt(t[1], t[2]); t[1] = o[31:16]; t[2] = o[15:0];
    o = srt(t[4], t[5]); t[4] = o[31:16]; t[5] = o[15:0];
    o = srt(t[7], t[8]); t[7] = o[31:16]; t[8] = o[15:0];
    t[3] = (t[0] > t[3]) ? t[0] : t[3];
    t[5] = (t[5] < t[8]) ? t[5] : t[8];
    for (ri5 = 0; ri5 < 9; ri5 = ri5 + 1) s2[ri5] <= t[ri5];
    // stage 3: sort(4,7); p6 = max(3,6); p4 = max(1,4); p2 = min(2,5); p4 = min(4,7)
    for (ri5 = 0; ri5 < 9; ri5 = ri5 + 1) t[ri5] = s2[ri5];
    o = srt(t[4], t[7]); t[4] = o[31:16]; t[7] = o[15:0];
    t[6] = (t[3] > t[6]) ? t[3] : t[6];
    t[4] = (t[1] > t[4]) ? t[1] : t[4];
    t[2] = (t[2] < t[5]) ? t[2] : t[5];
    t[4] = (t[4] < t[7]) ? t[4] : t[7];
    for (ri5 = 0; ri5 < 9; ri5 = ri5 + 1) s3[ri5] <= t[ri5];
    // stage 4: sort(4,2); p4 = max(6,4)
    for (ri5 = 0; ri5 < 9; ri5 = ri5 + 1) t[ri5] = s3[ri5];
    o = srt(t[4], t[2]); t[4] = o[31:16]; t[2] = o[15:0];
    t[4] = (t[6] > t[4]) ? t[6] : t[4];
    for (ri5 = 0; ri5 < 9; ri5 = ri5 + 1) s4[ri5] <= t[ri5];
    // stage 5: p4 = min(4,2): the median
    m5 <= (s4[4] < s4[2]) ? s4[4] : s4[2];

    v1 <= go && !rst;  v2 <= v1 && !rst;  v3 <= v2 && !rst;  v4 <= v3 && !rst;  v5 <= v4 && !rst;
    c1 <= win[1][1];  c2 <= c1;  c3 <= c2;  c4 <= c3;  c5 <= c4;
    x1 <= cur_x;  x2 <= x1;  x3 <= x2;  x4 <= x3;  x5 <= x4;
    y1 <= cur_row;  y2 <= y1;  y3 <= y2;  y4 <= y3;  y5 <= y4;
end

// ---- the beat
wire real5 = y5 >= 0 && y5 < $signed({1'b0, height}) && x5 >= 0 && x5 < $signed({1'b0, width});
always @(posedge clk) begin
    o_valid <= v5 && real5 && !rst;
    o_user <= x5 == 0 && y5 == 0;
    o_last <= x5 == $signed({1'b0, width}) - 12'sd1;
    o_eof <= x5 == $signed({1'b0, width}) - 12'sd1 && y5 == $signed({1'b0, height}) - 12'sd1;
    if (!median || c5[15:0] == `SC_INVALID) begin
        o_data <= {5'b0, c5};
    end else if (m5 == `SC_INVALID) begin
        o_data <= {5'b0, 3'd`SC_REASON_MEDIAN, 8'd0, 16'd`SC_INVALID};
    end else begin
        o_data <= {5'b0, c5[26:16], m5};
    end
end

endmodule

`resetall
