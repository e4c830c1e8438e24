// Language: Verilog 2005

`resetall
`timescale 1ns / 1ps
`default_nettype none

/*
 * ci_sync: two-flop synchroniser of a WIDTH-bit value into clk's domain.
 *
 * The source must be a register in its own domain. A multi-bit value crosses safely only when
 * at most one of its bits changes at a time (gray code) or it holds still for longer than three
 * clocks of the destination. Latency 2 clocks. No reset: the flops start at INIT.
 * Parameters are checked at elaboration: WIDTH >= 1.
 */
module ci_sync #
(
    parameter WIDTH = 1,
    parameter [WIDTH-1:0] INIT = {WIDTH{1'b0}}
)
(
    input  wire             clk,
    input  wire [WIDTH-1:0] in,
    output wire [WIDTH-1:0] out
);

// parameter checks: an instance that breaks one fails to elaborate, naming the rule
generate
    if (WIDTH < 1) begin : g_check_width
        ci_sync_parameter_WIDTH_must_be_at_least_1 width_too_small();
    end
endgenerate

(* ASYNC_REG = "TRUE" *) reg [WIDTH-1:0] meta_reg = INIT;
(* ASYNC_REG = "TRUE" *) reg [WIDTH-1:0] sync_reg = INIT;

always @(posedge clk) begin
    meta_reg <= in;
    sync_reg <= meta_reg;
end

assign out = sync_reg;

endmodule

`resetall
