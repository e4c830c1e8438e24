// Language: Verilog 2005

`resetall
`timescale 1ns / 1ps
`default_nettype none

/*
 * ci_lfifo: the line FIFO of one camera, from its pixel clock (wclk) to aclk (rclk).
 *
 * A dual-clock block RAM of 2**AW words and gray-coded pointers (AW + 1 bits, so a full FIFO is
 * told from an empty one). The write side (ci_rx) owns the addressing: it writes any word at
 * any address (w_en, w_addr, w_data) and publishes w_commit, the binary pointer up to which the
 * words are complete; only committed words become visible to the read side, so the writer can
 * reserve a header slot, fill a line behind it and discard the line again. w_rptr is the read
 * pointer as the write side sees it (2-3 wclk clocks late: free space is never overestimated).
 *
 * Read side: r_avail = committed words not yet read (a register view: 3-4 rclk clocks after the
 * commit); r_en reads the oldest one, r_data holds it one clock later. r_en while !r_avail is
 * ignored. r_flush (synchronous) empties the FIFO by moving the read pointer to the committed
 * write pointer: the pointers are never cleared, so neither side needs the other's reset.
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
 * Write pointer: gray register in wclk, synchronised into rclk
 */
reg  [AW:0] wgray_reg = {(AW + 1){1'b0}};
wire [AW:0] wgray_r;

always @(posedge wclk) begin
    wgray_reg <= bin2gray(w_commit);
end

ci_sync #(.WIDTH(AW + 1)) wsync_inst (.clk(rclk), .in(wgray_reg), .out(wgray_r));

/*
 * Read pointer: binary and gray registers in rclk, synchronised into wclk
 */
reg  [AW:0] rptr_reg = {(AW + 1){1'b0}};
reg  [AW:0] rgray_reg = {(AW + 1){1'b0}};
reg  [AW:0] wptr_r_reg = {(AW + 1){1'b0}};
wire [AW:0] rgray_w;

wire read = r_en && r_avail;

always @(posedge rclk) begin
    wptr_r_reg <= gray2bin(wgray_r);
    if (r_flush) begin
        rptr_reg <= wptr_r_reg;
    end else if (read) begin
        rptr_reg <= rptr_reg + 1'b1;
    end
    rgray_reg <= bin2gray(r_flush ? wptr_r_reg : rptr_reg + {{AW{1'b0}}, read});
    if (read) begin
        r_data <= mem[rptr_reg[AW-1:0]];
    end
end

assign r_avail = rptr_reg != wptr_r_reg;

ci_sync #(.WIDTH(AW + 1)) rsync_inst (.clk(wclk), .in(rgray_reg), .out(rgray_w));

assign w_rptr = gray2bin(rgray_w);

endmodule

`resetall
