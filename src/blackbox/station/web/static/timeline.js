// The health timeline's PNG export: the station serves the SVG (the same picture as the
// page's); this draws it on a canvas at twice its size and saves that as a PNG.
"use strict";
(function () {
  const link = document.getElementById("timeline-png");
  if (!link) return;

  // Redraw the page's timeline when the station pushes a change (at most every 2 s):
  // the server draws it (escaped SVG), parsed here as XML, never as HTML.
  const box = document.querySelector(".timeline-box");
  let last = 0, pending = false;
  function redraw() {
    pending = false; last = Date.now();
    fetch(link.href + "&links=1", { credentials: "same-origin" })
      .then(function (reply) { return reply.ok ? reply.text() : Promise.reject(reply.status); })
      .then(function (text) {
        const svg = new DOMParser().parseFromString(text, "image/svg+xml").documentElement;
        if (svg.nodeName !== "svg") return;
        box.replaceChildren(document.importNode(svg, true));
        document.body.dataset.timeline = String(Date.now());
      })
      .catch(function () { /* the next change tries again */ });
  }
  document.addEventListener("station:state", function () {
    if (pending || !box) return;
    pending = true;
    setTimeout(redraw, Math.max(0, 2000 - (Date.now() - last)));
  });

  link.addEventListener("click", function (event) {
    event.preventDefault();
    fetch(link.href, { credentials: "same-origin" })
      .then(function (reply) {
        if (!reply.ok) throw new Error("timeline export: HTTP " + reply.status);
        return reply.text();
      })
      .then(function (text) {
        const image = new Image();
        image.onload = function () {
          const canvas = document.createElement("canvas");
          canvas.width = image.naturalWidth * 2;
          canvas.height = image.naturalHeight * 2;
          const context = canvas.getContext("2d");
          context.scale(2, 2);
          context.drawImage(image, 0, 0);
          const save = document.createElement("a");
          save.href = canvas.toDataURL("image/png");
          save.download = link.dataset.png || "timeline.png";
          document.body.appendChild(save);
          save.click();
          save.remove();
        };
        image.src = "data:image/svg+xml;charset=utf-8," + encodeURIComponent(text);
      });
  });
})();
