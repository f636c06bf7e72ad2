//! Tests of `data`'s modules: reading and writing data sets, images,
//! arrays, point clouds and cameras.

mod export;
mod formats {
    mod idr;
}
mod image;
mod normalize;
mod npy;
mod points;
mod view;
mod view_image;
