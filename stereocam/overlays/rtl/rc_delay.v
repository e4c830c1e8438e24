// Language: Verilog 2005

`include "prelude.vh"

/*
 * rc_delay: a fixed delay line of LATENCY registers (LATENCY >= 0; 0 is a
 * wire), for the fields that ride along the rectify core's pixel pipeline.
 *
 * Latency: LATENCY clocks. Throughput: 1 word per clock, never stalls.
 * Reset: synchronous, active high, to zero when RESET is 1 (for valid bits);
 * with RESET 0 the registers are not reset (data, so they can become SRLs).
 * Parameters are checked at elaboration: WIDTH >= 1, LATENCY >= 0, RESET 0 or 1.
 */
module rc_delay #
(
    parameter WIDTH = 1,
    parameter LATENCY = 1,
    parameter RESET = 0
)
(
    input  wire             clk,
    input  wire             rst,
    input  wire [WIDTH-1:0] in,
    output wire [WIDTH-1:0] out
);

// parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
// unnamed block: it holds nothing in a build that passes)
generate
    // verilator lint_off GENUNNAMED
    if (WIDTH < 1) rc_delay_parameter_WIDTH_must_be_at_least_1 width_too_small();
    if (LATENCY < 0) rc_delay_parameter_LATENCY_must_be_at_least_0 latency_negative();
    if (RESET != 0 && RESET != 1) rc_delay_parameter_RESET_must_be_0_or_1 reset_invalid();
    // verilator lint_on GENUNNAMED
endgenerate

generate
    if (LATENCY == 0) begin : g_wire
        assign out = in;
    end else begin : g_regs
        // stage i at [WIDTH*i +: WIDTH]; stage LATENCY-1 is the output
        reg [WIDTH*LATENCY-1:0] stages_reg = {WIDTH*LATENCY{1'b0}};

        if (LATENCY == 1) begin : g_one
            always @(posedge clk) begin
                stages_reg <= in;
                if (rst && RESET != 0) begin
                    stages_reg <= {WIDTH*LATENCY{1'b0}};
                end
            end
        end else begin : g_many
            always @(posedge clk) begin
                stages_reg <= {stages_reg[0 +: WIDTH*(LATENCY-1)], in};
                if (rst && RESET != 0) begin
                    stages_reg <= {WIDTH*LATENCY{1'b0}};
                end
            end
        end

        assign out = stages_reg[WIDTH*(LATENCY-1) +: WIDTH];
    end
endgenerate

endmodule

`resetall
