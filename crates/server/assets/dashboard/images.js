// Live images without flicker. The API's images need the bearer token, so they are fetched as
// blobs and shown through object URLs. A new image is decoded off-screen first and only then
// swapped into the visible <img>: the old picture stays on screen until the new one can be
// painted at once, so there is never a blank or half-drawn frame. The previous object URL is
// revoked after the swap, so memory stays flat however long the page polls.

export async function showBlob(img, blob) {
  const url = URL.createObjectURL(blob);
  const next = new Image();
  next.src = url;
  try {
    await next.decode();
  } catch (e) {
    URL.revokeObjectURL(url);
    throw e;
  }
  const old = img.dataset.objectUrl;
  img.dataset.objectUrl = url;
  img.src = url;
  img.dataset.updates = String(Number(img.dataset.updates || 0) + 1);
  if (old) {
    // The decoded picture is in the image cache, so the swap is immediate; the old URL is no
    // longer needed once the new one has loaded (or failed).
    const release = () => URL.revokeObjectURL(old);
    if (img.complete) release();
    else {
      img.addEventListener('load', release, { once: true });
      img.addEventListener('error', release, { once: true });
    }
  }
}

export function releaseImage(img) {
  if (img.dataset.objectUrl) {
    URL.revokeObjectURL(img.dataset.objectUrl);
    delete img.dataset.objectUrl;
  }
}
