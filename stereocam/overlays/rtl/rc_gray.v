// Language: Verilog 2005

`include "prelude.vh"

/*
 * rc_gray: the gray value of one RGB tap, (77 R + 150 G + 29 B + 128) >> 8
 * (RECTIFY_CORE.md, "Gray of a tap"; the demosaic stage's formula).
 * The constant products are written as shifts and adds (no multiplier).
 *
 * Input: {B, G, R} (R in bits 7:0, as in the stream). Output: {Y, B, G, R}.
 * Latency: 2 clocks. Throughput: 1 per clock, never stalls, no reset.
 */
module rc_gray
(
    input  wire        clk,
    input  wire [23:0] rgb,
    output wire [31:0] rgby
);

wire [7:0] r = rgb[7:0];
wire [7:0] g = rgb[15:8];
wire [7:0] b = rgb[23:16];

// stage 1: 77 R = 64 R + 8 R + 4 R + R; 150 G = 128 G + 16 G + 4 G + 2 G; 29 B = 16 B + 8 B + 4 B + B
reg [14:0] r77_reg;
reg [15:0] g150_reg;
reg [12:0] b29_reg;
reg [23:0] rgb_1_reg;

// stage 2: the sum, rounded
reg [7:0]  y_reg;
reg [23:0] rgb_2_reg;

wire [16:0] sum = {2'b00, r77_reg} + {1'b0, g150_reg} + {4'b0000, b29_reg} + 17'd128;

always @(posedge clk) begin
    r77_reg <= ({1'b0, r, 6'd0} + {4'd0, r, 3'd0}) + ({5'd0, r, 2'd0} + {7'd0, r});
    g150_reg <= ({1'b0, g, 7'd0} + {4'd0, g, 4'd0}) + ({6'd0, g, 2'd0} + {7'd0, g, 1'd0});
    b29_reg <= ({1'b0, b, 4'd0} + {2'd0, b, 3'd0}) + ({3'd0, b, 2'd0} + {5'd0, b});
    rgb_1_reg <= rgb;

    y_reg <= sum[15:8];
    rgb_2_reg <= rgb_1_reg;
end

assign rgby = {y_reg, rgb_2_reg};

// the sum is below 2^16; its low byte is the dropped fraction
// verilator lint_off UNUSEDSIGNAL
wire unused_ok = &{1'b0, sum};
// verilator lint_on UNUSEDSIGNAL

endmodule

`resetall
