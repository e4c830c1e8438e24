// Language: Verilog 2005

`include "prelude.vh"

`include "camera_in_spec.vh"

/*
 * ci_demosaic: one output pixel of one camera from its 3x3 neighbourhood of 10-bit samples
 * (borders already mirrored by the caller): bilinear R, G, B (stereocam/overlays/spec/camera_in.py,
 * KERNELS), each as a sum S of weight-4 taps, rounded to 8 bits as min((S + 8) >> 4, 255),
 * and gray (77 R + 150 G + 29 B + 128) >> 8 (spec/pixel.py).
 *
 * win = {a_l, a_m, a_r, c_l, c_m, c_r, b_l, b_m, b_r} (a: row above, c: the pixel's row,
 * b: row below; l, m, r: columns), a_l in the top bits. red_row / red_col: the pixel is on a
 * row / column that holds red samples (R site: both; B site: neither; Gr: red_row only; Gb:
 * red_col only).
 *
 * Output rgby = {Y, B, G, R}, R in bits 7:0 (the stream's byte order).
 * Latency 4 clocks, throughput 1 per clock, never stalls, no reset.
 */
module ci_demosaic
(
    input  wire                     clk,
    input  wire [9*`CI_RAW_W-1:0]   win,
    input  wire                     red_row,
    input  wire                     red_col,
    output wire [31:0]              rgby
);

localparam RW = `CI_RAW_W;
localparam SW = RW + 2;  // sums of weight 4

wire [RW-1:0] a_l = win[8*RW +: RW];
wire [RW-1:0] a_m = win[7*RW +: RW];
wire [RW-1:0] a_r = win[6*RW +: RW];
wire [RW-1:0] c_l = win[5*RW +: RW];
wire [RW-1:0] c_m = win[4*RW +: RW];
wire [RW-1:0] c_r = win[3*RW +: RW];
wire [RW-1:0] b_l = win[2*RW +: RW];
wire [RW-1:0] b_m = win[1*RW +: RW];
wire [RW-1:0] b_r = win[0*RW +: RW];

// stage 1: the five sums
reg [SW-1:0] same_reg, cross_reg, diag_reg, hpair_reg, vpair_reg;
reg          red_row_1_reg, red_col_1_reg;

wire [RW:0] h_sum = {1'b0, c_l} + {1'b0, c_r};
wire [RW:0] v_sum = {1'b0, a_m} + {1'b0, b_m};
wire [RW:0] d_top = {1'b0, a_l} + {1'b0, a_r};
wire [RW:0] d_bot = {1'b0, b_l} + {1'b0, b_r};

always @(posedge clk) begin
    same_reg <= {c_m, 2'b00};
    cross_reg <= {1'b0, h_sum} + {1'b0, v_sum};
    diag_reg <= {1'b0, d_top} + {1'b0, d_bot};
    hpair_reg <= {h_sum, 1'b0};
    vpair_reg <= {v_sum, 1'b0};
    red_row_1_reg <= red_row;
    red_col_1_reg <= red_col;
end

// stage 2: choose per site, round, saturate
reg [SW-1:0] s_r, s_g, s_b;

always @* begin
    case ({red_row_1_reg, red_col_1_reg})
        2'b11: begin s_r = same_reg;  s_g = cross_reg; s_b = diag_reg;  end  // R
        2'b00: begin s_r = diag_reg;  s_g = cross_reg; s_b = same_reg;  end  // B
        2'b10: begin s_r = hpair_reg; s_g = same_reg;  s_b = vpair_reg; end  // Gr
        default: begin s_r = vpair_reg; s_g = same_reg; s_b = hpair_reg; end  // Gb
    endcase
end

// verilator lint_off UNUSEDSIGNAL
function [7:0] to8(input [SW-1:0] s);
    reg [SW:0] rounded;  // its low OUT_SHIFT bits are the dropped fraction
    begin
        rounded = {1'b0, s} + `CI_OUT_ROUND;
        to8 = (rounded[SW:`CI_OUT_SHIFT] > `CI_OUT_MAX) ? `CI_OUT_MAX : rounded[`CI_OUT_SHIFT +: 8];
    end
endfunction
// verilator lint_on UNUSEDSIGNAL

reg [7:0] r_reg, g_reg, b_reg;

always @(posedge clk) begin
    r_reg <= to8(s_r);
    g_reg <= to8(s_g);
    b_reg <= to8(s_b);
end

// stages 3 and 4: gray, (77 R + 150 G + 29 B + 128) >> 8: the rectify core's rc_gray, the same formula
rc_gray gray_inst (
    .clk(clk),
    .rgb({b_reg, g_reg, r_reg}),
    .rgby(rgby)
);

endmodule

`resetall
