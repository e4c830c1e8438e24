// Language: Verilog 2005

`include "prelude.vh"

/*
 * sc_census: the census windows of both images (STEREO_CORE.md step 1).
 *
 * Per slot (4 `run` clocks, `phase` 0..3) for the slot's pixel (row y, column
 * x, held for the slot): phase 0 reads column x + 4 of the line buffer (all
 * 8 row slots; only when 0 <= x + 4 < width); phase 2 shifts the 7x9 windows
 * of both images one column left and fills the right column with rows
 * y - 3 .. y + 3 of that column, 255 outside the image; phase 3 loads the
 * census words of the window's centre, pixel (x, y), and the left gray values
 * the edge tests need: IL(x, y), IL(x - 1, y), IL(x, y - 1), IL(x + 1, y - 1).
 * Census bit i compares neighbour i (row by row from the top left, centre
 * skipped) with the centre: 1 when darker.
 *
 * Latency: the outputs of a slot's pixel are loaded at the end of its phase 3
 * and hold through the next slot (until its phase 3). Every register and the
 * line-buffer read are enabled by `run`, so the unit holds while it is 0.
 * No reset (data only; the first 9 slots of a row fill the window).
 */
module sc_census #
(
    parameter MAX_WIDTH = 752,
    parameter AW = $clog2(MAX_WIDTH)
)
(
    input  wire               clk,
    input  wire               run,
    input  wire [1:0]         phase,
    input  wire signed [11:0] row,
    input  wire signed [11:0] col,
    input  wire [10:0]        width,
    input  wire [10:0]        height,

    // line buffer read port (sc_linebuf)
    output wire               lb_re,
    output wire [AW-1:0]      lb_raddr,
    input  wire [127:0]       lb_rdata,

    output reg  [61:0]        cl,
    output reg  [61:0]        cr,
    output reg  [7:0]         g_c,
    output reg  [7:0]         g_l,
    output reg  [7:0]         g_a,
    output reg  [7:0]         g_u
);

localparam NB = 62;  // census bits

// the column read this slot
wire signed [12:0] rcol = {col[11], col} + 13'sd4;
wire col_ok = !rcol[12] && rcol < $signed({2'b00, width});
wire [12:0] rcol_u = rcol;

assign lb_re = run && phase == 2'd0 && col_ok;
assign lb_raddr = rcol_u[AW-1:0];

// the new window column, rows y - 3 .. y + 3 (row r at [16*r +: 16])
reg [7*16-1:0] newcol;
integer r;
reg [31:0] r32;
reg signed [12:0] yr;
reg [12:0] yr_u;
always @* begin
    for (r = 0; r < 7; r = r + 1) begin
        r32 = r;
        yr = {row[11], row} + $signed(r32[12:0]) - 13'sd3;
        yr_u = yr;
        if (col_ok && !yr[12] && yr < $signed({2'b00, height})) begin
            newcol[16*r +: 16] = lb_rdata[16*yr_u[2:0] +: 16];
        end else begin
            newcol[16*r +: 16] = 16'hFFFF;
        end
    end
end

// windows: row r (y - 3 + r), column c (x - 4 + c) at [8*(9*r + c) +: 8]
reg [7*9*8-1:0] win_l;
reg [7*9*8-1:0] win_r;
integer c;
always @(posedge clk) begin
    if (run && phase == 2'd2) begin
        for (r = 0; r < 7; r = r + 1) begin
            for (c = 0; c < 8; c = c + 1) begin
                win_l[8*(9*r + c) +: 8] <= win_l[8*(9*r + c + 1) +: 8];
                win_r[8*(9*r + c) +: 8] <= win_r[8*(9*r + c + 1) +: 8];
            end
            win_l[8*(9*r + 8) +: 8] <= newcol[16*r +: 8];
            win_r[8*(9*r + 8) +: 8] <= newcol[16*r + 8 +: 8];
        end
    end
end

// census words of the centre (row 3, column 4)
reg [NB-1:0] census_l;
reg [NB-1:0] census_r;
integer dy, dx, bit_i;
always @* begin
    bit_i = 0;
    census_l = {NB{1'b0}};
    census_r = {NB{1'b0}};
    for (dy = 0; dy < 7; dy = dy + 1) begin
        for (dx = 0; dx < 9; dx = dx + 1) begin
            if (dy != 3 || dx != 4) begin
                census_l[bit_i] = win_l[8*(9*dy + dx) +: 8] < win_l[8*(9*3 + 4) +: 8];
                census_r[bit_i] = win_r[8*(9*dy + dx) +: 8] < win_r[8*(9*3 + 4) +: 8];
                bit_i = bit_i + 1;
            end
        end
    end
end

always @(posedge clk) begin
    if (run && phase == 2'd3) begin
        cl <= census_l;
        cr <= census_r;
        g_c <= win_l[8*(9*3 + 4) +: 8];
        g_l <= win_l[8*(9*3 + 3) +: 8];
        g_a <= win_l[8*(9*2 + 4) +: 8];
        g_u <= win_l[8*(9*2 + 5) +: 8];
    end
end

endmodule

`resetall
