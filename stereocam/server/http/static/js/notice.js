// Messages out of sight (issue 24, item 4). #messages never covers the views: on a narrow screen
// it sits in the page's flow above them (style.css). An error that comes while it is scrolled out
// of sight (the person is at a panel further down) would go unseen, so a small notice in a corner
// says how many errors wait above; a click scrolls them into view. It goes when they are in view
// or dismissed. On a wide screen the messages are always in sight (fixed over the side column).
import { $ } from "./core.js";

export function initMessageNotice() {
  const box = $("messages");
  const notice = document.createElement("button");
  notice.type = "button";
  notice.id = "messages-notice";
  notice.className = "messages-notice";
  notice.setAttribute("data-testid", "messages-notice");
  notice.hidden = true;
  document.body.append(notice);
  let inView = true;
  const update = () => {
    const n = box.querySelectorAll(".msg-error").length;
    const inFlow = getComputedStyle(box).position !== "fixed";
    notice.hidden = inView || !inFlow || n === 0;
    notice.textContent = "⚠ " + n + (n === 1 ? " error" : " errors") + " above ↑";
  };
  new IntersectionObserver((entries) => {
    inView = entries[entries.length - 1].isIntersecting;
    update();
  }).observe(box);
  new MutationObserver(update).observe(box, { childList: true });
  window.addEventListener("resize", update);
  notice.addEventListener("click", () => box.scrollIntoView({ block: "start" }));
}
