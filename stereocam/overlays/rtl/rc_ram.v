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
 * SLICE > 0 keeps the word as arrays of SLICE bits side by side (the last one
 * narrower where SLICE does not divide WIDTH): a block RAM's aspect ratio is
 * the tools' choice, and for a deep, wide word they take the fewest blocks,
 * 512 x 72 several deep, and choose between their outputs with LUTs; slices as
 * narrow as a block's deep mode (18 bits for 2K words, 9 for 4K) are one block
 * deep each, for a few blocks more (the stereo core's RAMs). SLICE 0: one array.
 * No reset (block RAM contents and its output register are not reset).
 * Parameters are checked at elaboration: WIDTH >= 1, DEPTH >= 2, 2**AW >= DEPTH,
 * SLICE >= 0.
 */
module rc_ram #
(
    parameter WIDTH = 24,
    parameter DEPTH = 1024,
    parameter AW = $clog2(DEPTH),
    parameter SLICE = 0
)
(
    input  wire             clk,

    input  wire             we,
    input  wire [AW-1:0]    waddr,
    input  wire [WIDTH-1:0] wdata,

    input  wire             re,
    input  wire [AW-1:0]    raddr,
    output wire [WIDTH-1:0] rdata
);

// parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
// unnamed block: it holds nothing in a build that passes)
generate
    // verilator lint_off GENUNNAMED
    if (WIDTH < 1) rc_ram_parameter_WIDTH_must_be_at_least_1 width_too_small();
    if (DEPTH < 2) rc_ram_parameter_DEPTH_must_be_at_least_2 depth_too_small();
    if ((1 << AW) < DEPTH) rc_ram_parameter_AW_too_small_for_DEPTH aw_too_small();
    if (SLICE < 0) rc_ram_parameter_SLICE_must_be_at_least_0 slice_negative();
    // verilator lint_on GENUNNAMED
endgenerate

localparam SW = (SLICE > 0 && SLICE < WIDTH) ? SLICE : WIDTH;  // a slice's width
localparam N = (WIDTH + SW - 1) / SW;                           // slices

genvar k;
generate
    for (k = 0; k < N; k = k + 1) begin : g_slice
        localparam W = (k == N - 1) ? WIDTH - SW * (N - 1) : SW;
        (* ram_style = "block" *)
        reg [W-1:0] mem [0:DEPTH-1];

        always @(posedge clk) begin
            if (we) begin
                mem[waddr] <= wdata[SW*k +: W];
            end
        end

        reg [W-1:0] read_reg;
        reg         re_reg = 1'b0;
        reg [W-1:0] out_reg;
        always @(posedge clk) begin
            if (re) begin
                read_reg <= mem[raddr];
            end
            re_reg <= re;
            if (re_reg) begin
                out_reg <= read_reg;
            end
        end
        assign rdata[SW*k +: W] = out_reg;
    end
endgenerate

endmodule

`resetall
