// Language: Verilog 2005

`include "prelude.vh"

`include "camera_in_spec.vh"

/*
 * ci_rx: one MT9V034 parallel receiver, in that camera's PIXCLK domain (pclk), writing the
 * camera's line FIFO (ci_lfifo) as records (stereocam/overlays/spec/camera_in.py, "Words of the line FIFOs"):
 *
 *   LINE header {first, tag, len}, then len PIXEL words; EOF {err, tag} when FRAME_VALID falls.
 *
 * DOUT, LINE_VALID and FRAME_VALID are registered on the rising edge of pclk (one clock, the
 * input flops), and every decision is taken on those registers. A frame starts when
 * FRAME_VALID rises after the receiver has seen it low (never in the middle of a frame after a
 * reset); its tag is the aclk side's frame tag (tag_gray, synchronised here) at that moment. A
 * line's header slot is reserved when LINE_VALID rises; when it falls the header is written and
 * the line committed (made visible to aclk) in the same clock. One clock of LINE_VALID low
 * between lines is enough.
 *
 * Loss: a line longer than MAX_WIDTH, or one that does not fit the FIFO (one word always stays
 * free for the EOF), is discarded with the rest of its frame, and the frame's EOF says err; a
 * line cut by FRAME_VALID falling is discarded, err. The EOF is written in a later clock (the
 * write port is busy with the header when both signals fall together) and, if the FIFO is full,
 * as soon as there is room; a frame that starts while an EOF still waits is skipped entirely
 * (no records: the aclk side sees its tag missing).
 *
 * Reset (rst, synchronous, from aclk through a synchroniser): drops the line in progress and
 * waits for FRAME_VALID low. The FIFO pointers are never cleared.
 * Parameters are checked at elaboration: 1 <= MAX_WIDTH < 2**CI_LEN_W, 2**AW >= MAX_WIDTH + 2.
 */
module ci_rx #
(
    parameter MAX_WIDTH = 752,
    parameter AW = 11
)
(
    input  wire                    pclk,
    input  wire                    rst,

    input  wire [`CI_RAW_W-1:0]    data,
    input  wire                    line_valid,
    input  wire                    frame_valid,
    input  wire [`CI_TAG_W-1:0]    tag_gray,     // from aclk (gray code, one bit changes at a time)

    output wire                    fv,           // FRAME_VALID as registered here (for aclk's tag)

    output reg                     w_en,
    output reg  [AW-1:0]           w_addr,
    output reg  [`CI_REC_W-1:0]    w_data,
    output wire [AW:0]             w_commit,
    input  wire [AW:0]             w_rptr
);

localparam integer DEPTH = 1 << AW;
localparam PW = AW + 1;
localparam LW = `CI_LEN_W;
localparam TW = `CI_TAG_W;
localparam [`CI_REC_KIND_W-1:0] K_PIXEL = `CI_REC_PIXEL;
localparam [`CI_REC_KIND_W-1:0] K_LINE = `CI_REC_LINE;
localparam [`CI_REC_KIND_W-1:0] K_EOF = `CI_REC_EOF;
localparam integer MAX_LEN_I = MAX_WIDTH;
localparam [LW-1:0] MAX_LEN = MAX_LEN_I[LW-1:0];
localparam integer PAD = `CI_REC_W - `CI_REC_KIND_W - `CI_RAW_W;

// parameter checks: an instance that breaks one fails to elaborate, naming the rule (in an
// unnamed block: it holds nothing in a build that passes)
// (a line's length must fit the header's field; the FIFO must hold a longest line, its header and an EOF)
generate
    // verilator lint_off GENUNNAMED
    if (MAX_WIDTH < 1 || MAX_WIDTH >= (1 << LW))
        ci_rx_parameter_MAX_WIDTH_must_fit_the_length_field max_width_invalid();
    if ((1 << AW) < MAX_WIDTH + 2) ci_rx_parameter_AW_too_small_for_MAX_WIDTH aw_too_small();
    // verilator lint_on GENUNNAMED
endgenerate

/*
 * Input flops and the frame tag
 */
(* IOB = "TRUE" *) reg [`CI_RAW_W-1:0] d_reg = {`CI_RAW_W{1'b0}};
(* IOB = "TRUE" *) reg                 lv_reg = 1'b0;
(* IOB = "TRUE" *) reg                 fv_reg = 1'b0;
reg lv_q_reg = 1'b0;
reg fv_q_reg = 1'b0;

always @(posedge pclk) begin
    d_reg <= data;
    lv_reg <= line_valid;
    fv_reg <= frame_valid;
    lv_q_reg <= lv_reg;
    fv_q_reg <= fv_reg;
end

assign fv = fv_reg;

wire [TW-1:0] tag_g;
ci_sync #(.WIDTH(TW)) tag_sync_inst (.clk(pclk), .in(tag_gray), .out(tag_g));

function [TW-1:0] gray2bin(input [TW-1:0] g);
    integer i;
    begin
        gray2bin[TW-1] = g[TW-1];
        for (i = TW - 2; i >= 0; i = i - 1) begin
            gray2bin[i] = gray2bin[i + 1] ^ g[i];
        end
    end
endfunction

wire [TW-1:0] tag_b = gray2bin(tag_g);

/*
 * State
 */
reg [PW-1:0] tent_reg = {PW{1'b0}};     // next free word (tentative)
reg [PW-1:0] commit_reg = {PW{1'b0}};   // words up to here are complete
reg [AW-1:0] hdr_reg = {AW{1'b0}};      // the header slot of the line in progress
reg [LW-1:0] len_reg = {LW{1'b0}};
reg [TW-1:0] tag_reg = {TW{1'b0}};
reg          ready_reg = 1'b0;          // FRAME_VALID seen low since reset
reg          frame_reg = 1'b0;          // writing this frame
reg          drop_reg = 1'b0;           // dropping the rest of this frame
reg          line_reg = 1'b0;           // a line is in progress
reg          first_reg = 1'b0;          // the next line is the frame's first
reg          err_reg = 1'b0;            // this frame lost something
reg          eof_reg = 1'b0;            // an EOF waits to be written
reg          eof_err_reg = 1'b0;
reg [TW-1:0] eof_tag_reg = {TW{1'b0}};

assign w_commit = commit_reg;

wire [PW-1:0] used = tent_reg - w_rptr;
localparam integer ROOM3_I = DEPTH - 3;
localparam integer ROOM2_I = DEPTH - 2;
localparam integer ROOM1_I = DEPTH - 1;
localparam [PW-1:0] ROOM3 = ROOM3_I[PW-1:0];
localparam [PW-1:0] ROOM2 = ROOM2_I[PW-1:0];
localparam [PW-1:0] ROOM1 = ROOM1_I[PW-1:0];
wire room3 = used <= ROOM3;   // header + pixel, and the EOF's word
wire room2 = used <= ROOM2;   // pixel, and the EOF's word
wire room1 = used <= ROOM1;   // the EOF

wire fv_rise = fv_reg && !fv_q_reg;
wire fv_fall = !fv_reg && fv_q_reg;
wire lv_rise = lv_reg && !lv_q_reg;
wire lv_hold = lv_reg && lv_q_reg;
wire lv_fall = !lv_reg && lv_q_reg;

// the frame as the line logic sees it this clock (a line may start with the frame)
wire starting = ready_reg && fv_rise && !eof_reg;
wire active = (frame_reg || starting) && fv_reg && !drop_reg;

wire [`CI_REC_W-1:0] pixel_word = {K_PIXEL, {PAD{1'b0}}, d_reg};
wire [`CI_REC_W-1:0] line_word = {K_LINE, first_reg, tag_reg, len_reg};
wire [`CI_REC_W-1:0] eof_word = {K_EOF, eof_err_reg, eof_tag_reg, {LW{1'b0}}};

always @(posedge pclk) begin
    w_en <= 1'b0;
    if (rst) begin
        ready_reg <= 1'b0;
        frame_reg <= 1'b0;
        drop_reg <= 1'b0;
        line_reg <= 1'b0;
        eof_reg <= 1'b0;
        tent_reg <= commit_reg;
    end else begin
        if (!ready_reg && !fv_reg) begin
            ready_reg <= 1'b1;
        end
        if (ready_reg && fv_rise) begin
            frame_reg <= !eof_reg;
            drop_reg <= 1'b0;
            first_reg <= 1'b1;
            err_reg <= 1'b0;
            tag_reg <= tag_b;
        end

        if (active && lv_rise) begin
            if (room3) begin
                hdr_reg <= tent_reg[AW-1:0];
                w_en <= 1'b1;
                w_addr <= tent_reg[AW-1:0] + 1'b1;
                w_data <= pixel_word;
                tent_reg <= tent_reg + {{(PW - 2){1'b0}}, 2'd2};
                len_reg <= {{(LW - 1){1'b0}}, 1'b1};
                line_reg <= 1'b1;
            end else begin
                drop_reg <= 1'b1;
                err_reg <= 1'b1;
            end
        end else if (line_reg && lv_hold && fv_reg) begin
            if (len_reg == MAX_LEN || !room2) begin
                tent_reg <= commit_reg;
                line_reg <= 1'b0;
                drop_reg <= 1'b1;
                err_reg <= 1'b1;
            end else begin
                w_en <= 1'b1;
                w_addr <= tent_reg[AW-1:0];
                w_data <= pixel_word;
                tent_reg <= tent_reg + 1'b1;
                len_reg <= len_reg + 1'b1;
            end
        end else if (line_reg && lv_fall) begin
            w_en <= 1'b1;
            w_addr <= hdr_reg;
            w_data <= line_word;
            commit_reg <= tent_reg;
            first_reg <= 1'b0;
            line_reg <= 1'b0;
        end else if (line_reg && !fv_reg) begin
            // FRAME_VALID fell in the middle of a line
            tent_reg <= commit_reg;
            line_reg <= 1'b0;
        end else if (eof_reg && room1) begin
            w_en <= 1'b1;
            w_addr <= tent_reg[AW-1:0];
            w_data <= eof_word;
            tent_reg <= tent_reg + 1'b1;
            commit_reg <= tent_reg + 1'b1;
            eof_reg <= 1'b0;
        end

        if (frame_reg && fv_fall) begin
            frame_reg <= 1'b0;
            eof_reg <= 1'b1;
            eof_tag_reg <= tag_reg;
            eof_err_reg <= err_reg || drop_reg || (line_reg && lv_reg);
        end
    end
end

endmodule

`resetall
