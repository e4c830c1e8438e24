// Language: Verilog 2001

`resetall
`timescale 1ns / 1ps
`default_nettype none

/*
 * AXI4-Stream register slice (skid buffer): the HDL test infrastructure's own
 * example module (tests/hdl/test_infra.py), not part of the rectify core.
 *
 * Latency: 1 clock from an accepted input beat to m_axis_tvalid.
 * Throughput: 1 beat per clock, with or without backpressure. Every output,
 * s_axis_tready included, comes straight from a register, so the slice cuts
 * all combinational paths between its two sides; a skid register holds the
 * one beat accepted in the clock in which the output stalls.
 * Frame and line boundaries: TUSER (start of frame) and TLAST (end of line)
 * travel with their beat unchanged; the slice never looks at them.
 * Reset: synchronous, active high; both registers empty, s_axis_tready low
 * during reset and high from the clock after it.
 */
module axis_reg #
(
    // Width of TDATA in bits (one 64-bit pixel per beat)
    parameter DATA_WIDTH = 64,
    // Width of TUSER in bits
    parameter USER_WIDTH = 1
)
(
    input  wire                   clk,
    input  wire                   rst,

    /*
     * AXI4-Stream input
     */
    input  wire [DATA_WIDTH-1:0]  s_axis_tdata,
    input  wire                   s_axis_tvalid,
    output wire                   s_axis_tready,
    input  wire                   s_axis_tlast,
    input  wire [USER_WIDTH-1:0]  s_axis_tuser,

    /*
     * AXI4-Stream output
     */
    output wire [DATA_WIDTH-1:0]  m_axis_tdata,
    output wire                   m_axis_tvalid,
    input  wire                   m_axis_tready,
    output wire                   m_axis_tlast,
    output wire [USER_WIDTH-1:0]  m_axis_tuser
);

// output register
reg [DATA_WIDTH-1:0] m_axis_tdata_reg = {DATA_WIDTH{1'b0}};
reg                  m_axis_tvalid_reg = 1'b0, m_axis_tvalid_next;
reg                  m_axis_tlast_reg = 1'b0;
reg [USER_WIDTH-1:0] m_axis_tuser_reg = {USER_WIDTH{1'b0}};

// skid register
reg [DATA_WIDTH-1:0] skid_tdata_reg = {DATA_WIDTH{1'b0}};
reg                  skid_tvalid_reg = 1'b0, skid_tvalid_next;
reg                  skid_tlast_reg = 1'b0;
reg [USER_WIDTH-1:0] skid_tuser_reg = {USER_WIDTH{1'b0}};

reg s_axis_tready_reg = 1'b0, s_axis_tready_next;

// datapath control
reg store_input_to_output;
reg store_input_to_skid;
reg store_skid_to_output;

assign s_axis_tready = s_axis_tready_reg;

assign m_axis_tdata  = m_axis_tdata_reg;
assign m_axis_tvalid = m_axis_tvalid_reg;
assign m_axis_tlast  = m_axis_tlast_reg;
assign m_axis_tuser  = m_axis_tuser_reg;

always @* begin
    m_axis_tvalid_next = m_axis_tvalid_reg;
    skid_tvalid_next = skid_tvalid_reg;

    store_input_to_output = 1'b0;
    store_input_to_skid = 1'b0;
    store_skid_to_output = 1'b0;

    if (m_axis_tready || !m_axis_tvalid_reg) begin
        // output register free this clock
        if (skid_tvalid_reg) begin
            // drain the skid register first (input is not ready this clock)
            m_axis_tvalid_next = 1'b1;
            skid_tvalid_next = 1'b0;
            store_skid_to_output = 1'b1;
        end else begin
            // pass the input through (a bubble if no beat is accepted)
            m_axis_tvalid_next = s_axis_tvalid && s_axis_tready_reg;
            store_input_to_output = 1'b1;
        end
    end else if (s_axis_tvalid && s_axis_tready_reg) begin
        // output stalled: keep the beat accepted this clock in the skid register
        skid_tvalid_next = 1'b1;
        store_input_to_skid = 1'b1;
    end

    // accept input whenever the skid register will be empty
    s_axis_tready_next = !skid_tvalid_next;
end

always @(posedge clk) begin
    m_axis_tvalid_reg <= m_axis_tvalid_next;
    skid_tvalid_reg <= skid_tvalid_next;
    s_axis_tready_reg <= s_axis_tready_next;

    if (rst) begin
        m_axis_tvalid_reg <= 1'b0;
        skid_tvalid_reg <= 1'b0;
        s_axis_tready_reg <= 1'b0;
    end
end

// datapath (no reset)
always @(posedge clk) begin
    if (store_input_to_output) begin
        m_axis_tdata_reg <= s_axis_tdata;
        m_axis_tlast_reg <= s_axis_tlast;
        m_axis_tuser_reg <= s_axis_tuser;
    end else if (store_skid_to_output) begin
        m_axis_tdata_reg <= skid_tdata_reg;
        m_axis_tlast_reg <= skid_tlast_reg;
        m_axis_tuser_reg <= skid_tuser_reg;
    end

    if (store_input_to_skid) begin
        skid_tdata_reg <= s_axis_tdata;
        skid_tlast_reg <= s_axis_tlast;
        skid_tuser_reg <= s_axis_tuser;
    end
end

endmodule

`resetall
