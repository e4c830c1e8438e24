// Language: Verilog 2005

`include "prelude.vh"

`include "stereo_spec.vh"

/*
 * sc_input: the stereo core's AXI4-Stream slave. Writes each beat's left and right gray bytes
 * into the front's line buffer (8 rows, row r in place r mod 8) and counts complete rows.
 *
 * A frame starts with a TUSER beat, accepted only while the scheduler can start a frame
 * (`accept_frame`); a row ends at column WIDTH - 1. A row may be written once phase A no longer
 * reads the row 8 above it (row r needs r <= `row_limit`, phase A's row + 4). SIZE_ERROR (`size_error`, one
 * clock) when TLAST is not at column WIDTH - 1 (an early TLAST ends the row; the rest of a long
 * row is dropped up to its TLAST), when TUSER comes inside a frame (the frame's missing rows are
 * counted as arrived, so the frame still completes, and the beat waits to start the next frame),
 * or when a beat without TUSER comes between frames (dropped).
 * Throughput: one beat a clock while rows may be written. Reset: synchronous, active high.
 */
module sc_input
(
    input  wire         clk,
    input  wire         rst,

    input  wire [63:0]  s_tdata,
    input  wire         s_tuser,
    input  wire         s_tlast,
    input  wire         s_tvalid,
    output wire         s_tready,

    input  wire         enable,
    input  wire [10:0]  width,
    input  wire [10:0]  height,
    input  wire         accept_frame,
    output wire         frame_begin,      // this clock accepts a frame's first beat
    input  wire [10:0]  row_limit,        // phase A's row + 4 (height + 4 or more: every row may come)

    output reg  [10:0]  rows_in = 11'd0,  // complete rows of the frame
    output wire         lb_we,
    output wire [10:0]  lb_col,
    output wire [10:0]  lb_row,
    output wire [15:0]  lb_data,
    output reg          size_error = 1'b0
);

reg         in_frame = 1'b0;
reg         skipping = 1'b0;   // dropping the rest of a long row, up to its TLAST
reg [10:0]  col = 11'd0;

wire row_ok = rows_in <= row_limit;
// A TUSER beat inside a frame is not taken: it ends this frame and then starts the next.
assign s_tready = enable && (in_frame ? (!s_tuser && (skipping || row_ok))
                                      : (!s_tuser || accept_frame));
wire take = s_tvalid && s_tready;
assign frame_begin = take && !in_frame && s_tuser;
wire writing = take && ((in_frame && !skipping) || frame_begin);
assign lb_we = writing;
assign lb_col = frame_begin ? 11'd0 : col;
assign lb_row = frame_begin ? 11'd0 : rows_in;
assign lb_data = {s_tdata[`SC_IN_RIGHT_GRAY_BYTE*8 +: 8], s_tdata[`SC_IN_LEFT_GRAY_BYTE*8 +: 8]};

// The end-of-row and last-row tests kept as flags beside col and rows_in (from the handshake
// through these comparisons into in_frame was a path over the period): col_last is
// col == width - 1, row_last rows_in + 1 == height, each set when its counter changes.
reg  col_last = 1'b0;
reg  row_last = 1'b0;
wire width_1 = width == 11'd1;
wire height_1 = height == 11'd1;
wire row_end = writing && (s_tlast || (frame_begin ? width_1 : col_last));
wire last_row = frame_begin ? height_1 : row_last;

always @(posedge clk) begin
    size_error <= 1'b0;
    if (rst) begin
        in_frame <= 1'b0;
        skipping <= 1'b0;
        col <= 11'd0;
        col_last <= width_1;
        rows_in <= 11'd0;
        row_last <= height_1;
    end else if (take) begin
        if (frame_begin) begin
            in_frame <= 1'b1;
            rows_in <= 11'd0;
            row_last <= height_1;
            col <= 11'd1;
            col_last <= width == 11'd2;
        end
        if (!in_frame && !s_tuser) begin
            size_error <= 1'b1;  // between frames, not a frame's first beat: dropped
        end
        if (skipping) begin
            if (s_tlast) skipping <= 1'b0;
        end else if (writing) begin
            if (row_end) begin
                col <= 11'd0;
                col_last <= width_1;
                rows_in <= (frame_begin ? 11'd0 : rows_in) + 11'd1;
                row_last <= frame_begin ? height == 11'd2 : rows_in + 11'd2 == height;
                if (s_tlast != (frame_begin ? width_1 : col_last)) begin
                    size_error <= 1'b1;
                    skipping <= !s_tlast;  // a long row: drop the rest up to TLAST
                end
                if (last_row) begin
                    in_frame <= 1'b0;
                end
            end else begin
                col <= (frame_begin ? 11'd0 : col) + 11'd1;
                col_last <= frame_begin ? width == 11'd2 : col + 11'd2 == width;
            end
        end
    end
    if (!rst && enable && in_frame && s_tvalid && s_tuser) begin
        // TUSER inside a frame: the frame ends here (missing rows count as arrived)
        size_error <= 1'b1;
        rows_in <= height;
        row_last <= 1'b0;
        in_frame <= 1'b0;
        skipping <= 1'b0;
    end
end

endmodule

`resetall
