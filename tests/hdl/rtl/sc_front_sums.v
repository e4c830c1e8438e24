// Language: Verilog 2005

`resetall
`timescale 1ns / 1ps
`default_nettype none

`ifndef SC_FRONT_FRAMES
`define SC_FRONT_FRAMES 1  // frames in the sums file (the bench's define)
`endif

/*
 * A test double of the stereo core's sc_front (tests only): the same ports, but the sums S come
 * from a file the bench writes ($readmemh of SUMS: word ((frame * height + y) * width + x) * 4 + g
 * holds group g of pixel (x, y), lane j in bits 10 j + 9 .. 10 j), so the back end of the core
 * (sc_winners onwards) can be co-simulated against the model's own sums. A pixel's group g leaves
 * one clock after the run clock of phase g of its slot; the frame number counts up after each
 * frame's last pixel, wrapping at FRAMES.
 */
module sc_front #
(
    parameter MAX_WIDTH = 64,
    parameter MAX_DISP = 32,
    parameter PARALLEL = 8,
    parameter SUMS = "sums.hex",
    parameter WORDS = 65536,
    parameter FRAMES = `SC_FRONT_FRAMES
)
(
    input  wire clk, input wire rst,
    input  wire lb_we, input wire [10:0] lb_col, input wire [10:0] lb_row, input wire [15:0] lb_data,
    input  wire [10:0] width, input wire [10:0] height, input wire [7:0] num_disp,
    input  wire [7:0] p1, input wire [7:0] p2, input wire [7:0] p2_edge, input wire [7:0] edge_thresh,
    input  wire run, input wire [1:0] phase, input wire signed [11:0] row, input wire signed [11:0] col,
    output reg m_valid = 1'b0, output reg [1:0] m_group, output reg [10:0] m_x, output reg [10:0] m_y,
    output reg [PARALLEL*10-1:0] m_sum
);

reg [PARALLEL*10-1:0] mem [0:WORDS-1];
initial $readmemh(SUMS, mem);

reg [7:0] frame = 8'd0;
wire real_px = row >= 0 && row < $signed({1'b0, height}) && col >= 0 && col < $signed({1'b0, width});
wire [31:0] index = (((frame * height) + row) * width + col) * 4 + phase;

always @(posedge clk) begin
    m_valid <= 1'b0;
    if (rst) begin
        frame <= 8'd0;
    end else if (run && real_px) begin
        m_valid <= 1'b1;
        m_group <= phase;
        m_x <= col[10:0];
        m_y <= row[10:0];
        m_sum <= mem[index];
        if (row == $signed({1'b0, height}) - 1 && col == $signed({1'b0, width}) - 1 && phase == 2'd3) begin
            frame <= (frame + 8'd1 == FRAMES) ? 8'd0 : frame + 8'd1;
        end
    end
end

endmodule

`resetall
