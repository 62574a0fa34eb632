// Click to enlarge: each figure of a page (notebook outputs, page images) opens at full size in a new tab; a figure
// shown much smaller than it was drawn (a strip of panels) says so under it.
document.addEventListener("DOMContentLoaded", function () {
  document.querySelectorAll("article.bd-article img").forEach(function (img) {
    if (img.closest("a[href]")) return;
    const link = document.createElement("a");
    link.href = img.getAttribute("src");
    link.target = "_blank";
    link.className = "tr-enlarge";
    link.title = "Click to enlarge";
    img.parentNode.insertBefore(link, img);
    link.appendChild(img);
    function hint() {
      if (img.naturalWidth && img.clientWidth < 0.6 * img.naturalWidth) {
        const note = document.createElement("div");
        note.className = "tr-enlarge-hint";
        note.textContent = "Click the figure to see it at full size.";
        link.insertAdjacentElement("afterend", note);
      }
    }
    if (img.complete) hint(); else img.addEventListener("load", hint);
  });
});
