// Language: Verilog 2005

`resetall
`timescale 1ns / 1ps
`default_nettype none

`include "stereo_spec.vh"

/*
 * sc_diag: the right image's winners for step 7's left-right check (STEREO_CORE.md, step 6):
 * dR(xr) = the d with the lowest S(xr + d, d), the lowest d on ties, over d < num_disp and
 * xr + d < width, from the same sums as the left winners (no second pass over the images).
 *
 * A systolic array of MAX_DISP cells: after pixel x of a row, cell k holds the best (sum, d) so
 * far of the right image's column x - k. A pixel's group 0 shifts the array by one (a new row
 * starts it empty) and each group g updates cells PARALLEL*g .. PARALLEL*g + PARALLEL-1 with its
 * lanes (cell k takes S(x, k) when x - k >= 0, k < num_disp and it is strictly lower: d grows with
 * x, so the lowest d wins ties). The cell shifted out of the last place is final (it has seen
 * every d); so is every cell once a row's last pixel is in (`width - 1`): those are copied to a
 * flush buffer and written one a clock.
 * Out: a write port for the winners' RAM: address (row mod 3) * MAX_WIDTH + xr, 7-bit d.
 * Free running (no enable), from the front's groups in order. A row's winners are all written at
 * most `width` + 2 clocks after its last group.
 * Reset: synchronous, active high.
 */
module sc_diag #
(
    parameter MAX_WIDTH = 752,
    parameter MAX_DISP = 128,
    parameter PARALLEL = 32,
    parameter AW = $clog2(3 * MAX_WIDTH)
)
(
    input  wire                           clk,
    input  wire                           rst,

    input  wire [10:0]                    width,
    input  wire [7:0]                     num_disp,

    input  wire                           s_valid,
    input  wire [1:0]                     s_group,
    input  wire [10:0]                    s_x,
    input  wire [10:0]                    s_y,
    input  wire [PARALLEL*`SC_SUM_W-1:0]  s_sum,

    output reg                            w_en = 1'b0,
    output reg  [AW-1:0]                  w_addr,
    output reg  [6:0]                     w_d
);

localparam SW = `SC_SUM_W;
localparam [SW-1:0] BIG = {SW{1'b1}};

reg [SW-1:0] val [0:MAX_DISP-1];
reg [6:0]    dd  [0:MAX_DISP-1];
reg [10:0]   x_now;          // the column of the pixel in the array's place 0
reg [AW-1:0] base_now;       // its row's bank

`include "sc_bank.vh"

// the flush buffer: a finished row's winners, written out one a clock
reg [6:0]    fl_d [0:MAX_DISP-1];
reg [10:0]   fl_left = 11'd0;   // entries still to write (cell index fl_left - 1 next)
reg [10:0]   fl_x0;             // the column of cell 0 when copied
reg [AW-1:0] fl_base;

// the cell leaving the array at a shift
reg          ex_en = 1'b0;
reg [10:0]   ex_xr;
reg [AW-1:0] ex_base;
reg [6:0]    ex_d;

integer k1;
integer k3;
always @(posedge clk) begin
    ex_en <= 1'b0;
    if (s_valid) begin
        if (s_group == 0) begin
            // leaving: the last place's cell, column x - MAX_DISP of the same row
            ex_en <= s_x != 0 && s_x >= MAX_DISP;
            ex_xr <= s_x - MAX_DISP;
            ex_base <= base_now;
            ex_d <= dd[MAX_DISP-1];
            for (k1 = MAX_DISP - 1; k1 >= 0; k1 = k1 - 1) begin
                if (k1 < PARALLEL) begin
                    // place k1 gets this pixel's lane k1 against the shifted cell (empty at k1 = 0
                    // and on a new row)
                    if (k1 <= s_x && k1 < num_disp
                        && (k1 == 0 || s_x == 0 || s_sum[k1*SW +: SW] < val[k1-1])) begin
                        val[k1] <= s_sum[k1*SW +: SW];
                        dd[k1] <= k1;
                    end else if (k1 == 0 || s_x == 0) begin
                        val[k1] <= BIG;
                        dd[k1] <= 7'd0;
                    end else begin
                        val[k1] <= val[k1-1];
                        dd[k1] <= dd[k1-1];
                    end
                end else if (s_x == 0) begin
                    val[k1] <= BIG;
                    dd[k1] <= 7'd0;
                end else begin
                    val[k1] <= val[k1-1];
                    dd[k1] <= dd[k1-1];
                end
            end
            x_now <= s_x;
            base_now <= bank_base(s_y);
        end else begin
            for (k1 = 0; k1 < MAX_DISP; k1 = k1 + 1) begin
                if (k1 / PARALLEL == s_group && k1 <= x_now && k1 < num_disp
                    && s_sum[(k1 % PARALLEL)*SW +: SW] < val[k1]) begin
                    val[k1] <= s_sum[(k1 % PARALLEL)*SW +: SW];
                    dd[k1] <= k1;
                end
            end
        end
    end
    if (rst) begin
        ex_en <= 1'b0;
    end
end

// a row's last group: every cell of the row is final; copy them the clock after (updates done)
reg last_in = 1'b0;
always @(posedge clk) begin
    last_in <= s_valid && s_group == (MAX_DISP / PARALLEL) - 1 && x_now == width - 1 && !rst;
end

always @(posedge clk) begin
    w_en <= 1'b0;
    if (rst) begin
        fl_left <= 11'd0;
    end else if (last_in) begin
        for (k3 = 0; k3 < MAX_DISP; k3 = k3 + 1) fl_d[k3] <= dd[k3];
        fl_left <= (x_now + 1 < MAX_DISP) ? x_now + 11'd1 : MAX_DISP;
        fl_x0 <= x_now;
        fl_base <= base_now;
    end
    if (!rst && ex_en) begin
        w_en <= 1'b1;
        w_addr <= ex_base + ex_xr;
        w_d <= ex_d;
    end else if (!rst && !last_in && fl_left != 0) begin
        w_en <= 1'b1;
        w_addr <= fl_base + (fl_x0 - (fl_left - 11'd1));
        w_d <= fl_d[fl_left - 1];
        fl_left <= fl_left - 11'd1;
    end
end

endmodule

`resetall
