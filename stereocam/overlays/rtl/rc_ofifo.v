// Language: Verilog 2005

`resetall
`timescale 1ns / 1ps
`default_nettype none

/*
 * rc_ofifo: the rectify core's output FIFO, distributed RAM with a
 * registered output (first word fall through).
 *
 * The writer never overflows it: rc_datapath issues a pixel only while the
 * pixels in flight plus the words held here are fewer than DEPTH (credits),
 * so there is no full flag. The storage holds DEPTH words and the output
 * register one more.
 * Latency: a written word reaches m_valid 2 clocks later when the FIFO is
 * empty. Throughput: 1 word per clock in and out.
 * Frame and line boundaries: none; TUSER and TLAST travel inside the word.
 * Reset: synchronous, active high: empty.
 * Parameters are checked at elaboration: WIDTH >= 1, DEPTH a power of two >= 2.
 */
module rc_ofifo #
(
    parameter WIDTH = 67,
    parameter DEPTH = 32
)
(
    input  wire             clk,
    input  wire             rst,

    input  wire             wr_en,
    input  wire [WIDTH-1:0] wr_data,

    output wire [WIDTH-1:0] m_data,
    output wire             m_valid,
    input  wire             m_ready
);

localparam AW = $clog2(DEPTH);

// parameter checks: an instance that breaks one fails to elaborate, naming the rule
// (the pointers wrap at 2 * DEPTH and address the storage by their low AW bits: DEPTH = 2**AW)
generate
    if (WIDTH < 1) begin : g_check_width
        rc_ofifo_parameter_WIDTH_must_be_at_least_1 width_too_small();
    end
    if (DEPTH < 2 || (1 << AW) != DEPTH) begin : g_check_depth
        rc_ofifo_parameter_DEPTH_must_be_a_power_of_2_at_least_2 depth_invalid();
    end
endgenerate

(* ram_style = "distributed" *)
reg [WIDTH-1:0] mem [0:DEPTH-1];

reg [AW:0]      wr_ptr_reg = {AW+1{1'b0}};
reg [AW:0]      rd_ptr_reg = {AW+1{1'b0}};
reg [WIDTH-1:0] out_data_reg = {WIDTH{1'b0}};
reg             out_valid_reg = 1'b0;

wire empty = wr_ptr_reg == rd_ptr_reg;
wire load = !empty && (!out_valid_reg || m_ready);

assign m_data = out_data_reg;
assign m_valid = out_valid_reg;

always @(posedge clk) begin
    if (wr_en) begin
        mem[wr_ptr_reg[AW-1:0]] <= wr_data;
    end
end

always @(posedge clk) begin
    if (wr_en) begin
        wr_ptr_reg <= wr_ptr_reg + 1'b1;
    end
    if (load) begin
        out_data_reg <= mem[rd_ptr_reg[AW-1:0]];
        rd_ptr_reg <= rd_ptr_reg + 1'b1;
        out_valid_reg <= 1'b1;
    end else if (m_ready) begin
        out_valid_reg <= 1'b0;
    end

    if (rst) begin
        wr_ptr_reg <= {AW+1{1'b0}};
        rd_ptr_reg <= {AW+1{1'b0}};
        out_valid_reg <= 1'b0;
    end
end

endmodule

`resetall
