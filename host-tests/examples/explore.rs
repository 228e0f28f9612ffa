use host_tests::real::{read_columns, read_xyz};
use mag_cal_core::{calibrate, Config, Method, Thresholds};

fn main() {
    let loose = Thresholds {
        refuse_lack_of_fit: 1e9,
        refuse_fit_error: 1e9,
        ..Thresholds::DEFAULT
    };
    let files: Vec<(&str, Vec<[f64; 3]>)> = vec![
        ("icm", read_xyz("icm20948_mag_300.csv")),
        ("mag3", read_xyz("mag3_raw_541.csv")),
        ("magcal", read_xyz("magcal_25598.txt")),
        ("imu", read_columns("imu_gnss_1252.csv", [6, 7, 8])),
    ];
    for (name, y) in &files {
        for robust in [false, true] {
            for method in [Method::Adc2, Method::Adc2Iterated] {
                let cfg = Config {
                    method,
                    robust,
                    thresholds: loose,
                    ..Config::default()
                };
                match calibrate::<f64, _>(y, &cfg) {
                    Ok(f) => {
                        let r = f.report;
                        println!("{name} robust {robust} {method:?}: used {} drop {} scr {} rej {} fe {:.4} rms {:.4} lof {:.2} cov {:.3} rp {}", r.samples_used, r.samples_dropped, r.screened, r.rejected, r.quality.fit_error, r.radial_rms, r.quality.lack_of_fit, r.quality.coverage, r.robust_passes);
                    }
                    Err(e) => println!("{name} robust {robust} {method:?}: {e}"),
                }
            }
        }
    }
}
