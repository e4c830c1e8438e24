// Language: Verilog 2005

`include "prelude.vh"

/*
 * rc_ram: simple dual-port RAM, one write port and one read port on one
 * clock, written as a plain inferred array so that yosys and Vivado map it
 * to block RAM (the depth need not be a power of two). The one such RAM of
 * the rectify core (line buffers, side data) and the camera IPs (camera_in's
 * line buffers, frame_gate's frame FIFO).
 *
 * Latency: read data 2 clocks after the read address: the array's registered
 * read, then an output register (a block RAM's DO_REG in Vivado), each
 * loaded only for a read (`re`, and `re` one clock later), so the data holds
 * until the next read. Throughput: one write and one read per clock.
 * A read of the address written in the same clock returns the old data
 * (the line buffers never do that: see rc_datapath and camera_in).
 * No reset (block RAM contents and its output register are not reset).
 * Parameters are checked at elaboration: WIDTH >= 1, DEPTH >= 2, 2**AW >= DEPTH.
 */
module rc_ram #
(
    parameter WIDTH = 24,
    parameter DEPTH = 1024,
    parameter AW = $clog2(DEPTH)
)
(
    input  wire             clk,

    input  wire             we,
    input  wire [AW-1:0]    waddr,
    input  wire [WIDTH-1:0] wdata,

    input  wire             re,
    input  wire [AW-1:0]    raddr,
    output reg  [WIDTH-1:0] rdata
);

// parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
// unnamed block: it holds nothing in a build that passes)
generate
    // verilator lint_off GENUNNAMED
    if (WIDTH < 1) rc_ram_parameter_WIDTH_must_be_at_least_1 width_too_small();
    if (DEPTH < 2) rc_ram_parameter_DEPTH_must_be_at_least_2 depth_too_small();
    if ((1 << AW) < DEPTH) rc_ram_parameter_AW_too_small_for_DEPTH aw_too_small();
    // verilator lint_on GENUNNAMED
endgenerate

(* ram_style = "block" *)
reg [WIDTH-1:0] mem [0:DEPTH-1];

always @(posedge clk) begin
    if (we) begin
        mem[waddr] <= wdata;
    end
end

reg [WIDTH-1:0] read_reg;
reg             re_reg = 1'b0;

always @(posedge clk) begin
    if (re) begin
        read_reg <= mem[raddr];
    end
    re_reg <= re;
    if (re_reg) begin
        rdata <= read_reg;
    end
end

endmodule

`resetall
