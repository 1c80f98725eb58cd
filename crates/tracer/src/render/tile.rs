/// A rectangle of pixels: `width × height` starting at `(x0, y0)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct Tile {
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
}

/// A tile that does not lie inside its image.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("tile {width}x{height} at ({x0},{y0}) is empty or outside the {image_width}x{image_height} image")]
pub struct TileError {
    pub x0: u32,
    pub y0: u32,
    pub width: u32,
    pub height: u32,
    pub image_width: u32,
    pub image_height: u32,
}

impl Tile {
    /// The whole image.
    pub fn full(width: u32, height: u32) -> Self {
        Tile {
            x0: 0,
            y0: 0,
            width,
            height,
        }
    }

    pub fn pixel_count(&self) -> u64 {
        self.width as u64 * self.height as u64
    }

    /// Checks that the tile is non-empty and inside a `w × h` image.
    pub fn check(&self, w: u32, h: u32) -> Result<(), TileError> {
        let inside = self.width > 0
            && self.height > 0
            && self.x0 as u64 + self.width as u64 <= w as u64
            && self.y0 as u64 + self.height as u64 <= h as u64;
        if inside {
            Ok(())
        } else {
            Err(TileError {
                x0: self.x0,
                y0: self.y0,
                width: self.width,
                height: self.height,
                image_width: w,
                image_height: h,
            })
        }
    }

    /// Row-major grid of `size × size` tiles covering a `w × h` image (edge tiles are smaller).
    pub fn grid(w: u32, h: u32, size: u32) -> Vec<Tile> {
        let size = size.max(1);
        let mut tiles = Vec::new();
        let mut y = 0;
        while y < h {
            let mut x = 0;
            while x < w {
                tiles.push(Tile {
                    x0: x,
                    y0: y,
                    width: size.min(w - x),
                    height: size.min(h - y),
                });
                x += size;
            }
            y += size;
        }
        tiles
    }
}
