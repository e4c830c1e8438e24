// Language: Verilog 2005

`include "prelude.vh"

/*
 * ci_sync: two-flop synchroniser of a WIDTH-bit value into clk's domain.
 *
 * The source must be a register in its own domain. A multi-bit value crosses safely only when
 * its changes are single gray steps at most one per destination clock, or it holds still while
 * the destination uses it (a handshake's data). Latency 2 clocks. No reset: the flops start at INIT.
 * Parameters are checked at elaboration: WIDTH >= 1.
 * Both flops carry ASYNC_REG; stereocam.xdc bounds the path into meta_reg (set_max_delay
 * -datapath_only, set_bus_skew).
 *
 * Simulation only (`define CI_SKEW_SIM, never in synthesis): each bit's change reaches meta_reg
 * 0 or 1 destination clocks late, drawn at random per change and per bit, the worst a real
 * crossing with a bounded skew can do; a bus that is not crossed safely then shows it.
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

// parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
// unnamed block: it holds nothing in a build that passes)
generate
    // verilator lint_off GENUNNAMED
    if (WIDTH < 1) ci_sync_parameter_WIDTH_must_be_at_least_1 width_too_small();
    // verilator lint_on GENUNNAMED
endgenerate

(* ASYNC_REG = "TRUE" *) reg [WIDTH-1:0] meta_reg = INIT;
(* ASYNC_REG = "TRUE" *) reg [WIDTH-1:0] sync_reg = INIT;

`ifdef CI_SKEW_SIM
// the value each bit had at the previous clock; a changed bit takes it once more with p = 1/2
reg [WIDTH-1:0] prev_reg = INIT;
reg [WIDTH-1:0] skewed;
reg [31:0]      draw;
integer         i;

always @(posedge clk) begin
    for (i = 0; i < WIDTH; i = i + 1) begin
        draw = $random;
        skewed[i] = (in[i] != prev_reg[i] && draw[7]) ? prev_reg[i] : in[i];
    end
    prev_reg <= in;
    meta_reg <= skewed;
    sync_reg <= meta_reg;
end
`else
always @(posedge clk) begin
    meta_reg <= in;
    sync_reg <= meta_reg;
end
`endif

assign out = sync_reg;

endmodule

`resetall
