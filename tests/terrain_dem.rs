//! DEM sampling on a GeoTIFF written here with GDAL, in another CRS than the survey's.

#![cfg(all(feature = "opencv", feature = "gdal", feature = "onnx"))]

use std::rc::Rc;

use gdal::DriverManager;
use gdal::raster::Buffer;
use gdal::spatial_ref::SpatialRef;
use geostride::survey::crs::{Crs, HeightKind};
use geostride::survey::frame::{Origin, SiteFrame, dem_surface};
use geostride::survey::{Gcp, Survey, SurveyFormat};
use geostride::terrain::{HeightSurface, raster};
use nalgebra::{Vector2, Vector3};

/// A UTM 31N GeoTIFF, 0.5 m pixels, heights z = 30 + 0.01·(x − 500000) − 0.02·(y − 5600000).
fn write_dem(path: &std::path::Path) {
    let (w, h) = (400usize, 300usize);
    let (x0, y0, px) = (499_900.0, 5_600_080.0, 0.5);
    let driver = DriverManager::get_driver_by_name("GTiff").unwrap();
    let mut ds = driver
        .create_with_band_type::<f32, _>(path, w, h, 1)
        .unwrap();
    ds.set_geo_transform(&[x0, px, 0.0, y0, 0.0, -px]).unwrap();
    ds.set_spatial_ref(&SpatialRef::from_epsg(32631).unwrap())
        .unwrap();
    let mut data = Vec::with_capacity(w * h);
    for r in 0..h {
        for c in 0..w {
            let (x, y) = (x0 + (c as f64 + 0.5) * px, y0 - (r as f64 + 0.5) * px);
            data.push((30.0 + 0.01 * (x - 500_000.0) - 0.02 * (y - 5_600_000.0)) as f32);
        }
    }
    let mut band = ds.rasterband(1).unwrap();
    let mut buf = Buffer::new((w, h), data);
    band.write((0, 0), (w, h), &mut buf).unwrap();
}

#[test]
fn dem_in_utm_sampled_from_a_survey_in_latitude_longitude() {
    let dir = tempfile::tempdir().unwrap();
    let tif = dir.path().join("dem.tif");
    write_dem(&tif);
    let (grid, wkt) = raster::load(&tif).unwrap();
    assert_eq!((grid.width, grid.height), (400, 300));

    // A survey in WGS 84 latitude/longitude around the DEM's area.
    let utm = Crs::new("EPSG:32631").unwrap();
    let pts: Vec<Gcp> = [
        (500_000.0, 5_600_000.0),
        (500_050.0, 5_600_020.0),
        (499_980.0, 5_599_990.0),
    ]
    .iter()
    .enumerate()
    .map(|(i, &(x, y))| {
        let (lon, lat) = utm.to_lon_lat(x, y).unwrap();
        Gcp::new(format!("P{i}"), Vector3::new(lon, lat, 30.0), i + 1)
    })
    .collect();
    let survey = Survey {
        source: "mem".into(),
        format: SurveyFormat::Csv,
        crs: Some("EPSG:4326".into()),
        height: HeightKind::Ellipsoidal,
        points: pts,
        dropped: vec![],
        warnings: vec![],
    };
    let frame = Rc::new(SiteFrame::new(&survey, &Origin::Centroid).unwrap());
    let dem = dem_surface(Rc::clone(&frame), grid, &wkt).unwrap();
    let origin_h = frame.tangent.as_ref().unwrap().origin.h;
    for &(x, y) in &[
        (500_000.0, 5_600_000.0),
        (500_031.7, 5_599_962.2),
        (499_951.3, 5_600_041.9),
    ] {
        let z = 30.0 + 0.01 * (x - 500_000.0) - 0.02 * (y - 5_600_000.0);
        let (lon, lat) = utm.to_lon_lat(x, y).unwrap();
        let local = frame.local_from_source(&Vector3::new(lon, lat, z)).unwrap();
        let h = dem.height(&Vector2::new(local.x, local.y)).unwrap();
        // f32 storage rounds heights to about 2e-6 m; bilinear is exact on a plane.
        assert!(
            (h - local.z).abs() < 1e-4,
            "at ({x}, {y}): {h} vs {}",
            local.z
        );
        assert!(
            (local.z - (z - origin_h)).abs() < 0.01,
            "U is a height difference"
        );
    }
    // Outside the raster: no height.
    assert!(dem.height(&Vector2::new(5_000.0, 0.0)).is_none());
}
