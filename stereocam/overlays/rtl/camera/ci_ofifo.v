// Language: Verilog 2005

`resetall
`timescale 1ns / 1ps
`default_nettype none

/*
 * ci_ofifo: the output FIFO, first-word fall-through, distributed RAM, one clock.
 *
 * A word moves in when s_valid (the writer never writes into a full FIFO: it counts credits)
 * and out when m_valid && m_ready; m_data is the oldest word and holds still while m_ready is
 * low. count (a register) is the number held. Latency 1 clock from a word in to m_valid; one
 * word per clock in and out. Synchronous active-high rst empties it.
 */
module ci_ofifo #
(
    parameter WIDTH = 66,
    parameter DEPTH = 16
)
(
    input  wire                       clk,
    input  wire                       rst,
    input  wire [WIDTH-1:0]           s_data,
    input  wire                       s_valid,
    output wire [WIDTH-1:0]           m_data,
    output wire                       m_valid,
    input  wire                       m_ready,
    output wire [$clog2(DEPTH+1)-1:0] count
);

localparam AW = $clog2(DEPTH);
localparam CW = $clog2(DEPTH + 1);

reg [WIDTH-1:0] mem [0:DEPTH-1];
reg [AW-1:0]    wr_ptr_reg = {AW{1'b0}};
reg [AW-1:0]    rd_ptr_reg = {AW{1'b0}};
reg [CW-1:0]    count_reg = {CW{1'b0}};

wire pop = m_ready && count_reg != {CW{1'b0}};

always @(posedge clk) begin
    if (s_valid) begin
        mem[wr_ptr_reg] <= s_data;
    end
end

always @(posedge clk) begin
    if (rst) begin
        wr_ptr_reg <= {AW{1'b0}};
        rd_ptr_reg <= {AW{1'b0}};
        count_reg <= {CW{1'b0}};
    end else begin
        if (s_valid) begin
            wr_ptr_reg <= wr_ptr_reg + 1'b1;
        end
        if (pop) begin
            rd_ptr_reg <= rd_ptr_reg + 1'b1;
        end
        count_reg <= count_reg + {{(CW - 1){1'b0}}, s_valid} - {{(CW - 1){1'b0}}, pop};
    end
end

assign m_data = mem[rd_ptr_reg];
assign m_valid = count_reg != {CW{1'b0}};
assign count = count_reg;

endmodule

`resetall
