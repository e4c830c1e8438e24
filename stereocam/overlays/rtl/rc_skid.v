// Language: Verilog 2005

`include "prelude.vh"

/*
 * rc_skid: a valid/ready register slice with a skid register (the rectify
 * core's input slice, in front of rc_datapath's input checking).
 *
 * Latency: 1 clock from an accepted beat to m_valid.
 * Throughput: 1 beat per clock, with or without backpressure. s_ready comes
 * straight from a register (it does not depend on s_valid or m_ready in the
 * same clock); the skid register holds the one beat accepted in the clock
 * in which the output stalls.
 * Frame and line boundaries: none; TUSER and TLAST travel inside `s_data`.
 * Reset: synchronous, active high: both registers empty, s_ready low in
 * reset and high from the clock after it.
 * Parameters are checked at elaboration: WIDTH >= 1.
 */
module rc_skid #
(
    parameter WIDTH = 66
)
(
    input  wire             clk,
    input  wire             rst,

    input  wire [WIDTH-1:0] s_data,
    input  wire             s_valid,
    output wire             s_ready,

    output wire [WIDTH-1:0] m_data,
    output wire             m_valid,
    input  wire             m_ready
);

// parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
// unnamed block: it holds nothing in a build that passes)
generate
    // verilator lint_off GENUNNAMED
    if (WIDTH < 1) rc_skid_parameter_WIDTH_must_be_at_least_1 width_too_small();
    // verilator lint_on GENUNNAMED
endgenerate

reg [WIDTH-1:0] out_data_reg = {WIDTH{1'b0}};
reg             out_valid_reg = 1'b0, out_valid_next;
reg [WIDTH-1:0] skid_data_reg = {WIDTH{1'b0}};
reg             skid_valid_reg = 1'b0, skid_valid_next;
reg             s_ready_reg = 1'b0;

reg store_in_to_out;
reg store_in_to_skid;
reg store_skid_to_out;

// ready next clock unless the skid register would fill: output taken, or room for one more
wire s_ready_early = m_ready || (!skid_valid_reg && (!out_valid_reg || !s_valid));

assign s_ready = s_ready_reg;
assign m_data = out_data_reg;
assign m_valid = out_valid_reg;

always @* begin
    out_valid_next = out_valid_reg;
    skid_valid_next = skid_valid_reg;
    store_in_to_out = 1'b0;
    store_in_to_skid = 1'b0;
    store_skid_to_out = 1'b0;

    if (s_ready_reg) begin
        if (m_ready || !out_valid_reg) begin
            out_valid_next = s_valid;
            store_in_to_out = 1'b1;
        end else begin
            skid_valid_next = s_valid;
            store_in_to_skid = 1'b1;
        end
    end else if (m_ready) begin
        out_valid_next = skid_valid_reg;
        skid_valid_next = 1'b0;
        store_skid_to_out = 1'b1;
    end
end

always @(posedge clk) begin
    s_ready_reg <= s_ready_early;
    out_valid_reg <= out_valid_next;
    skid_valid_reg <= skid_valid_next;

    if (store_in_to_out) begin
        out_data_reg <= s_data;
    end else if (store_skid_to_out) begin
        out_data_reg <= skid_data_reg;
    end
    if (store_in_to_skid) begin
        skid_data_reg <= s_data;
    end

    if (rst) begin
        s_ready_reg <= 1'b0;
        out_valid_reg <= 1'b0;
        skid_valid_reg <= 1'b0;
    end
end

endmodule

`resetall
