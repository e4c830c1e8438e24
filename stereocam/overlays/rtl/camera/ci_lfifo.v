// Language: Verilog 2005

`include "prelude.vh"

/*
 * ci_lfifo: the line FIFO of one camera, from its pixel clock (wclk) to aclk (rclk).
 *
 * A dual-clock block RAM of 2**AW words; pointers of AW + 1 bits (so a full FIFO is told from an
 * empty one). The write side (ci_rx) owns the addressing: it writes any word at any address (w_en,
 * w_addr, w_data) and publishes w_commit, the binary pointer up to which the words are complete;
 * only committed words become visible to the read side, so the writer can reserve a header slot,
 * fill a line behind it and discard the line again.
 *
 * Crossings (every one through ci_sync, each sample a value the source really held):
 * - write pointer, wclk -> rclk: a published pointer follows w_commit one word per wclk clock and
 *   crosses in gray code, so consecutive values differ in one bit and change at most once per wclk
 *   clock; rclk must be faster than wclk (aclk against PIXCLK). A line's words appear in order,
 *   from its header on, up to one line time after its commit.
 * - read pointer, rclk -> wclk: a req/ack handshake. The read side holds its binary pointer in a
 *   register and toggles req; the write side takes the held value (crossed beside req, which waits
 *   one more flop, so the value is settled) and answers with ack; only then is the next value
 *   loaded. w_rptr is thus a few wclk clocks late: free space is never overestimated. A flush's
 *   jump crosses like any other value.
 *
 * Read side: r_avail = visible words not yet read (a register view); r_en reads the oldest one,
 * r_data holds it one clock later. r_en while !r_avail is ignored: the reader must gate every read
 * by r_avail itself. r_flush (synchronous) empties the FIFO by moving the read pointer to the
 * visible write pointer: the pointers are never cleared, so neither side needs the other's reset.
 * Throughput: one word per clock on each side.
 */
module ci_lfifo #
(
    parameter WIDTH = 18,
    parameter AW = 11
)
(
    input  wire             wclk,
    input  wire             w_en,
    input  wire [AW-1:0]    w_addr,
    input  wire [WIDTH-1:0] w_data,
    input  wire [AW:0]      w_commit,
    output wire [AW:0]      w_rptr,

    input  wire             rclk,
    input  wire             r_flush,
    input  wire             r_en,
    output reg  [WIDTH-1:0] r_data,
    output wire             r_avail
);

function [AW:0] bin2gray(input [AW:0] b);
    bin2gray = b ^ (b >> 1);
endfunction

function [AW:0] gray2bin(input [AW:0] g);
    integer i;
    begin
        gray2bin[AW] = g[AW];
        for (i = AW - 1; i >= 0; i = i - 1) begin
            gray2bin[i] = gray2bin[i + 1] ^ g[i];
        end
    end
endfunction

(* ram_style = "block" *)
reg [WIDTH-1:0] mem [0:(1 << AW) - 1];

always @(posedge wclk) begin
    if (w_en) begin
        mem[w_addr] <= w_data;
    end
end

/*
 * Write pointer: a published pointer that follows w_commit a word per wclk clock, in gray code,
 * synchronised into rclk
 */
reg  [AW:0] wpub_reg = {(AW + 1){1'b0}};
reg  [AW:0] wgray_reg = {(AW + 1){1'b0}};
wire [AW:0] wgray_r;

always @(posedge wclk) begin
    if (wpub_reg != w_commit) begin
        wpub_reg <= wpub_reg + 1'b1;
    end
    wgray_reg <= bin2gray(wpub_reg);
end

ci_sync #(.WIDTH(AW + 1)) wsync_inst (.clk(rclk), .in(wgray_reg), .out(wgray_r));

/*
 * Read pointer: binary in rclk, crossed to wclk by a req/ack handshake
 */
reg  [AW:0] rptr_reg = {(AW + 1){1'b0}};
reg  [AW:0] wptr_r_reg = {(AW + 1){1'b0}};
reg  [AW:0] rhold_reg = {(AW + 1){1'b0}};    // the value in flight, still while req != ack
reg         rreq_reg = 1'b0;
wire        rack_r;

wire        read = r_en && r_avail;
wire [AW:0] rptr_next = r_flush ? wptr_r_reg : rptr_reg + {{AW{1'b0}}, read};

always @(posedge rclk) begin
    wptr_r_reg <= gray2bin(wgray_r);
    rptr_reg <= rptr_next;
    if (rack_r == rreq_reg) begin
        rhold_reg <= rptr_next;
        rreq_reg <= !rreq_reg;
    end
    if (read) begin
        r_data <= mem[rptr_reg[AW-1:0]];
    end
end

assign r_avail = rptr_reg != wptr_r_reg;

wire [AW:0] rhold_w;
wire        rreq_w;
reg         rreq_w_reg = 1'b0;   // req one flop behind the value: the value has settled when req arrives
reg         wack_reg = 1'b0;
reg  [AW:0] rptr_w_reg = {(AW + 1){1'b0}};

ci_sync #(.WIDTH(AW + 1)) rsync_inst (.clk(wclk), .in(rhold_reg), .out(rhold_w));
ci_sync reqsync_inst (.clk(wclk), .in(rreq_reg), .out(rreq_w));

always @(posedge wclk) begin
    rreq_w_reg <= rreq_w;
    if (rreq_w_reg != wack_reg) begin
        rptr_w_reg <= rhold_w;
        wack_reg <= rreq_w_reg;
    end
end

ci_sync acksync_inst (.clk(rclk), .in(wack_reg), .out(rack_r));

assign w_rptr = rptr_w_reg;

endmodule

`resetall
