// Language: Verilog 2005

`include "prelude.vh"

/*
 * rc_fifo: synchronous FIFO, valid/ready on both sides, distributed-RAM storage: the one FIFO
 * of the rectify core (rc_coord's coordinates, rc_datapath's output) and the camera IPs
 * (camera_in's and frame_gate's output FIFO); the output FIFOs' writers count credits and leave
 * s_ready unconnected.
 *
 * Holds up to DEPTH words; count is the number held (0..DEPTH, a register). s_ready =
 * count < DEPTH: a word moves in when s_valid && s_ready.
 *
 * SHOW_AHEAD = 1 (first-word fall-through): m_valid = count > 0 (a register) and m_data is
 * then the oldest word, read asynchronously from the RAM (LUTRAM read path to the
 * consumer); it moves out when m_valid && m_ready. Latency 1 clock from a word in to
 * m_valid; one word per clock in and out. s_ready depends on count only: when the FIFO is
 * full no word enters, even on a clock where one leaves. m_data holds still while m_ready
 * is low.
 * SHOW_AHEAD = 0 (read request): m_ready is a read request; when count > 0 on that clock
 * the oldest word is on m_data (a register) the next clock, with m_valid = 1 for that clock.
 * OUTPUT_REG = 1 (with SHOW_AHEAD = 1; the rectify core's output FIFO): the oldest word moves
 * into an output register whenever it is empty or being taken, so m_data and m_valid are
 * registers (nothing combinational reaches the consumer). Latency 2 clocks from a word in to
 * m_valid; one word per clock in and out; DEPTH words in the RAM and one in the register (count
 * is the RAM's). m_data and m_valid hold while m_ready is low.
 *
 * Frame and line boundaries: none; it knows words only. Reset: synchronous, active high:
 * empty (also the power-up state). Parameters are checked at elaboration: DEPTH >= 2,
 * SHOW_AHEAD 0 or 1, OUTPUT_REG 0 or 1 and only with SHOW_AHEAD 1.
 */
module rc_fifo #(
    parameter WIDTH = 8,
    parameter DEPTH = 16,       // words held; >= 2
    parameter SHOW_AHEAD = 1,
    parameter OUTPUT_REG = 0    // 1: the head in an output register (SHOW_AHEAD 1 only)
) (
    input  wire                          clk,
    input  wire                          rst,
    input  wire [WIDTH-1:0]              s_data,
    input  wire                          s_valid,
    output wire                          s_ready,
    output wire [WIDTH-1:0]              m_data,
    output wire                          m_valid,
    input  wire                          m_ready,
    output wire [$clog2(DEPTH+1)-1:0]    count
);
    localparam AW = (DEPTH > 1) ? $clog2(DEPTH) : 1;
    localparam CW = $clog2(DEPTH + 1);
    localparam integer  LAST_I = DEPTH - 1;
    localparam [AW-1:0] LAST = LAST_I[AW-1:0];
    localparam integer  FULL_I = DEPTH;
    localparam [CW-1:0] FULL = FULL_I[CW-1:0];

    // parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
    // unnamed block: it holds nothing in a build that passes)
    generate
        // verilator lint_off GENUNNAMED
        if (DEPTH < 2) rc_fifo_parameter_DEPTH_must_be_at_least_2 depth_too_small();
        if (SHOW_AHEAD != 0 && SHOW_AHEAD != 1)
            rc_fifo_parameter_SHOW_AHEAD_must_be_0_or_1 show_ahead_invalid();
        if (OUTPUT_REG != 0 && OUTPUT_REG != 1)
            rc_fifo_parameter_OUTPUT_REG_must_be_0_or_1 output_reg_invalid();
        if (OUTPUT_REG == 1 && SHOW_AHEAD != 1)
            rc_fifo_parameter_OUTPUT_REG_needs_SHOW_AHEAD_1 output_reg_needs_show_ahead();
        // verilator lint_on GENUNNAMED
    endgenerate

    (* ram_style = "distributed" *)  // LUT RAM in every mode (the OUTPUT_REG read is registered)
    reg [WIDTH-1:0] mem [0:DEPTH-1];
    reg [AW-1:0]    wr_ptr = {AW{1'b0}}, rd_ptr = {AW{1'b0}};
    reg [CW-1:0]    held = {CW{1'b0}};  // words in the FIFO
    reg             nonempty = 1'b0;    // held != 0
    reg             notfull = 1'b1;     // held != DEPTH

    function [AW-1:0] next_ptr(input [AW-1:0] ptr);
        next_ptr = (ptr == LAST) ? {AW{1'b0}} : ptr + 1'b1;
    endfunction

    reg             head_valid = 1'b0;  // OUTPUT_REG: the output register holds a word
    wire push = s_valid && notfull;
    wire pop = nonempty && (OUTPUT_REG ? (!head_valid || m_ready) : m_ready);
    wire [CW-1:0] held_next = held + {{CW-1{1'b0}}, push} - {{CW-1{1'b0}}, pop};

    always @(posedge clk) begin
        if (push) mem[wr_ptr] <= s_data;
    end

    always @(posedge clk) begin
        if (rst) begin
            wr_ptr   <= {AW{1'b0}};
            rd_ptr   <= {AW{1'b0}};
            held     <= {CW{1'b0}};
            nonempty <= 1'b0;
            notfull  <= 1'b1;
        end else begin
            if (push) wr_ptr <= next_ptr(wr_ptr);
            if (pop) rd_ptr <= next_ptr(rd_ptr);
            held     <= held_next;
            nonempty <= held_next != {CW{1'b0}};
            notfull  <= held_next != FULL;
        end
    end

    generate
        if (SHOW_AHEAD && OUTPUT_REG) begin : fwft_reg
            reg [WIDTH-1:0] head_data = {WIDTH{1'b0}};
            always @(posedge clk) begin
                if (rst) head_valid <= 1'b0;
                else if (pop) head_valid <= 1'b1;
                else if (m_ready) head_valid <= 1'b0;
                if (pop) head_data <= mem[rd_ptr];
            end
            assign m_data  = head_data;
            assign m_valid = head_valid;
        end else if (SHOW_AHEAD) begin : fwft
            assign m_data  = mem[rd_ptr];
            assign m_valid = nonempty;
        end else begin : request
            reg [WIDTH-1:0] out_data;
            reg             out_valid = 1'b0;
            always @(posedge clk) begin
                if (rst) out_valid <= 1'b0;
                else out_valid <= pop;
                if (pop) out_data <= mem[rd_ptr];
            end
            assign m_data  = out_data;
            assign m_valid = out_valid;
        end
    endgenerate

    assign s_ready = notfull;
    assign count   = held;
endmodule

`resetall
