// Language: Verilog 2005

`include "prelude.vh"

/*
 * sc_sched: paces the stereo core (STEREO_CORE.md, "RTL structure") in slots of 4 clocks and
 * sweeps of a frame.
 *
 * Between frames (`idle`, when the registers may make shadow parameters active) it lets sc_input
 * take a frame's first beat (`accept_frame`, unless an APPLY is pending: `hold`) and starts on it
 * (`frame_begin`).
 * Then it runs sweeps `row` = 0 .. height + 2, each of columns `col` = -PRE .. ncol - 1 with
 * ncol = max(width + 8, MAX_DISP + 32): phase A's row and column are (row, col), phase B's
 * (row - 2, col), phase C's (row - 3, col - 4). A slot starts only when the rows phase A reads
 * have arrived (`rows_in` > min(row + 3, height - 1)) and the output has room (`out_room`); once
 * started, `run` stays high for its 4 clocks (`phase` 0..3). After the last slot, `frame_done`.
 * Both tests are registered (`ready_q`), from the row and column the next clock will have and
 * this clock's `rows_in` and `out_room`: `run` fans out to every register and RAM of the core, so
 * it is one gate from registers, and a slot may start a clock later than its rows arrived
 * (`rows_in` only grows within a frame; the caller's `out_room` leaves a beat for the clock).
 * `row_limit` (phase A's row + 4, or `height` + 4 between frames and after the last row: the last
 * row the input may write) is a clock late.
 * Reset: synchronous, active high.
 */
module sc_sched #
(
    parameter MAX_DISP = 128,
    parameter PRE = 16
)
(
    input  wire               clk,
    input  wire               rst,

    input  wire               enable,
    input  wire [10:0]        width,
    input  wire [10:0]        height,
    input  wire [10:0]        rows_in,
    input  wire               frame_begin,
    input  wire               out_room,
    input  wire               hold,

    output wire               idle,
    output wire               accept_frame,
    output wire               run,
    output reg  [1:0]         phase = 2'd0,
    output reg  signed [11:0] row = 12'sd0,
    output reg  signed [11:0] col = 12'sd0,
    output reg  [1:0]         row_bank = 2'd0,  // row mod 3, kept beside row
    output wire [10:0]        row_limit,
    output wire               busy,
    output reg                frame_done = 1'b0
);

localparam S_IDLE = 1'b0, S_RUN = 1'b1;
reg        state = S_IDLE;
reg signed [11:0] ncol;

wire signed [11:0] h = $signed({1'b0, height});
wire signed [11:0] r_in = $signed({1'b0, rows_in});
wire sweep_end = phase == 2'd3 && col == ncol - 12'sd1;
// Phase A of row r may run when r >= height or rows min(r + 4, height) have arrived, that is
// r >= h || rows_in >= r + 4 || rows_in >= h. The row of the next clock is 0 at a frame's start,
// row + 1 after the last slot of a sweep, else row: the test is made for each and one is chosen
// (choosing the row first put the comparisons behind the choice: a path over the period).
wire all_in = r_in >= h;
wire ready_stay = row >= h || r_in >= row + 12'sd4 || all_in;
wire ready_next = row + 12'sd1 >= h || r_in >= row + 12'sd5 || all_in;
wire ready_first = r_in >= 12'sd4 || all_in;
reg ready_q = 1'b0;  // at phase 0: the rows have arrived and the output has room
always @(posedge clk) begin
    ready_q <= ((state == S_IDLE) ? ready_first : (run && sweep_end) ? ready_next : ready_stay) && out_room;
end
wire go = state == S_RUN && phase == 2'd0 && ready_q;
assign run = (state == S_RUN) && (phase != 2'd0 || go);
assign accept_frame = state == S_IDLE && enable && !hold;
assign busy = state == S_RUN;
assign idle = state == S_IDLE;
// Registered: it gates the input's TREADY (sc_input's row test), and from `row` through that test to
// the input's counters was the core's longest path. A clock late is safe: within a frame it only
// grows, so the input waits a clock longer at most; at a frame's start it is `height` for one more
// clock, when the input has at most one row.
// The input's limit is phase A's row + 4 (the adder here, not behind the input's comparison).
reg [10:0] row_limit_q = 11'd4;
always @(posedge clk) begin
    row_limit_q <= ((state == S_RUN && row < h) ? row[10:0] : height) + 11'd4;
end
assign row_limit = row_limit_q;

wire signed [11:0] wide = $signed({1'b0, width}) + 12'sd8;
wire signed [11:0] least = MAX_DISP + 32;

always @(posedge clk) begin
    frame_done <= 1'b0;
    if (rst) begin
        state <= S_IDLE;
        phase <= 2'd0;
    end else begin
        case (state)
            S_IDLE: begin
                if (frame_begin) begin
                    state <= S_RUN;
                    row <= 12'sd0;
                    row_bank <= 2'd0;
                    col <= -PRE;
                    phase <= 2'd0;
                    ncol <= (wide > least) ? wide : least;
                end
            end
            default: begin
                if (run) begin
                    phase <= phase + 2'd1;
                    if (phase == 2'd3) begin
                        if (col == ncol - 12'sd1) begin
                            col <= -PRE;
                            if (row == h + 12'sd2) begin
                                state <= S_IDLE;
                                frame_done <= 1'b1;
                            end else begin
                                row <= row + 12'sd1;
                                row_bank <= (row_bank == 2'd2) ? 2'd0 : row_bank + 2'd1;
                            end
                        end else begin
                            col <= col + 12'sd1;
                        end
                    end
                end
            end
        endcase
    end
end

endmodule

`resetall
